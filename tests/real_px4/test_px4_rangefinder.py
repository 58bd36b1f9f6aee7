"""PX4 v1.16 SIH's DISTANCE_SENSOR (streamed on the onboard link at 10 Hz, 0-100 m, downward, from
boot) read and used in the final descent ([mission.rangefinder], docs/rangefinder.md): the short
GPS-only delivery without the return, once on the estimate alone and once on the rangefinder. Both
record the rangefinder's height beside PX4's estimate: how far the estimate has drifted by the
final descent, and how fast the vehicle met the ground (the range's rate, the last 0.3 s before it
reads the ground)."""

from __future__ import annotations

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.events import EventKind
from companion_firmware.px4_sitl import Px4Sitl

pytestmark = pytest.mark.firmware

INSTANCE = 6  # udp 14546: beside the other tests' instance 0


def _config(mav, rangefinder: bool):  # type: ignore[no-untyped-def]
    config = mav.firmware_config("px4", f"udpin://127.0.0.1:{14540 + INSTANCE}", 30.0)
    mission = config.mission.model_copy(
        update={
            "return_home": False,
            "rangefinder": config.mission.rangefinder.model_copy(update={"enabled": rangefinder}),
        }
    )
    landing = config.landing.model_copy(update={"fusion": False, "use_camera": False, "use_uwb": False})
    policy = config.landing.policy.model_copy(update={"require_pad_lock": False})
    return config.model_copy(update={"mission": mission, "landing": landing.model_copy(update={"policy": policy})})


async def _fly(mav, px4_root, tmp_path, rangefinder: bool):  # type: ignore[no-untyped-def]
    config = _config(mav, rangefinder)
    trace: list[tuple[float, float, float, str]] = []  # time, range, the estimate's height, phase

    watch = mav.rangefinder_trace(trace)

    with Px4Sitl(px4_root, instance=INSTANCE, log_path=tmp_path / "px4.log"):
        ap = Px4Autopilot.from_config(config)
        ap.want_rangefinder = True  # recorded either way; used only with [mission.rangefinder] on
        shell, summary = await mav.fly(config, ap, watch, timeout_s=80.0)
    assert summary.delivered, summary.failure
    assert ap.telemetry.received.get("RangefinderReading", 0) > 100
    # the descent down to the first reading at the ground (its minimum, 0); when the flight's trace
    # ended before a 10 Hz reading said 0 (it once did, under CI load), its lowest reading
    first, last, sink = mav.descent_to_ground(trace, 0.05)
    landing = [first]
    drift = landing[0][2] - landing[0][1]  # the estimate's height - the rangefinder's at the final descent
    touchdown = next(e.time_s for e in shell.events if e.kind is EventKind.TOUCHDOWN)
    print(
        f"PX4 SIH rangefinder {'on' if rangefinder else 'off'}: final descent from {landing[0][1]:.2f} m "
        f"(estimate {landing[0][2]:.2f} m, drift {drift:+.2f} m), sink at the ground {sink:.2f} m/s, "
        f"ground -> touchdown {touchdown - last[0]:.2f} s"
    )
    return shell, drift, sink, landing[0][1]


async def test_px4_sih_final_descent_on_the_rangefinder(mav, px4_root, tmp_path):
    shell, _drift, sink, start_m = await _fly(mav, px4_root, tmp_path, rangefinder=True)
    gate = shell.mission.rangefinder
    assert gate is not None and gate.accepted > 20, gate.rejected if gate else None
    approach = shell.config.mission.final_descent_alt_m
    assert abs(start_m - approach) < 0.5, start_m  # the final descent began at its height by the rangefinder
    assert 0.5 * shell.config.mission.land_speed_m_s < sink < 1.3 * shell.config.mission.land_speed_m_s, sink


async def test_px4_sih_final_descent_on_the_estimate_alone(mav, px4_root, tmp_path):
    """The same flight flown on the estimate: the final descent starts wherever PX4's drifted height
    puts the approach height; the rangefinder is recorded, never used."""
    shell, drift, sink, start_m = await _fly(mav, px4_root, tmp_path, rangefinder=False)
    assert shell.mission.rangefinder is None
    assert sink > 0.5 * shell.config.mission.land_speed_m_s, sink  # it descended onto the ground
    approach = shell.config.mission.final_descent_alt_m
    assert abs(start_m + drift - approach) < 0.3, (start_m, drift)  # on the estimate's height
