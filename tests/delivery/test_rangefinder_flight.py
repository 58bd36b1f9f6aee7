"""The rangefinder in the final descent (docs/rangefinder.md), flown over real MAVLink against the
sim vehicle: the autopilot's height estimate drifts up 0.12 m/s while armed, 1.4 m by the final
descent (sim.height_estimate_drift_m_s; PX4 v1.16 SIH, GPS only, drifted 0.3-1.7 m in one 20 s
flight). On the estimate alone the final descent begins half a metre above the ground, still
sinking at the vector field's v5 (2 m/s), and the vehicle meets the ground fast. With
[mission.rangefinder] the DISTANCE_SENSOR the vehicle sends (ArduCopter's RNGFND1_TYPE = 100 SITL
rangefinder, noisy; PX4 SIH's) starts it at its height: the vehicle meets the ground at land speed."""

from __future__ import annotations

import math
import time

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.px4 import Px4Autopilot
from companion.estimation.rangefinder import Rejection
from companion.events import EventKind

pytestmark = pytest.mark.flight

DRIFT_M_S = 0.12  # 1.4 m by the final descent, 12 s after arming
ARDUCOPTER_RANGEFINDER = {"RNGFND1_TYPE": 100.0, "RNGFND1_MIN": 0.2, "RNGFND1_MAX": 7.0, "RNGFND1_ORIENT": 25.0}
PARAMS = {
    "ardupilot": {"GRIP_ENABLE": 1.0, **ARDUCOPTER_RANGEFINDER, "SIM_SONAR_RND": 0.02},
    "px4": {"SIH_DISTSNSR_MIN": 0.0, "SIH_DISTSNSR_MAX": 100.0},
}


def _config(mav, rangefinder: bool):  # type: ignore[no-untyped-def]
    """The short scenario, one way, on a height estimate drifting at DRIFT_M_S."""
    return mav.shipped_config(
        mission={"return_home": False, "descent": {"contact_time_s": 0.3}, "rangefinder": {"enabled": rangefinder}},
        sim={"height_estimate_drift_m_s": DRIFT_M_S},
    )


def _contact(sim) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """(vehicle time, true sink rate m/s) where the vehicle first met the ground after take-off."""
    log = sim.vehicle.truth_log
    up = next(i for i, s in enumerate(log) if -s.down_m > 1.0)
    i = next(i for i in range(up, len(log)) if -log[i].down_m < 0.03)
    return log[i].time_s, log[i - 1].down_m_s  # truth at 10 Hz: the last sample in the air


async def _fly(mav, port: int, dialect: str, rangefinder: bool):  # type: ignore[no-untyped-def]
    config = _config(mav, rangefinder)
    with mav.sim_vehicle(config, dialect, port, params=PARAMS[dialect]) as sim:
        url = f"udpin:127.0.0.1:{port}" if dialect == "ardupilot" else f"udpin://127.0.0.1:{port}"
        cls = ArduPilotAutopilot if dialect == "ardupilot" else Px4Autopilot
        ap = cls.from_config(config.model_copy(update={"connection": url}))
        offset = time.monotonic() - sim.now  # the shell's clock minus the vehicle's
        shell, summary = await mav.fly(config, ap)
    assert summary.delivered, summary.failure
    t_contact, sink = _contact(sim)
    touchdown = next(e for e in shell.events if e.kind is EventKind.TOUCHDOWN)
    td = sim.vehicle.touchdowns[0]
    error = math.hypot(td.north_m - config.mission.pad.north_m, td.east_m - config.mission.pad.east_m)
    m = shell.mission
    assert m.summary.pad_touchdown_ned is not None and m.pad_ned is not None
    by_estimate = math.hypot(*(m.summary.pad_touchdown_ned[i] - float(m.pad_ned[i]) for i in (0, 1)))
    print(f"{dialect} rangefinder {'on' if rangefinder else 'off'}: landing error by the estimate {by_estimate:.2f} m")
    return shell, ap, sink, touchdown.time_s - offset - t_contact, error


@pytest.mark.parametrize("dialect", ["ardupilot", "px4"])
async def test_the_rangefinder_starts_the_final_descent_at_its_height_on_a_biased_estimate(mav, udp_port, dialect):
    shell, ap, sink, decided_s, error = await _fly(mav, udp_port, dialect, rangefinder=True)
    gate = shell.mission.rangefinder
    assert gate is not None and gate.accepted > 10, (gate.accepted if gate else None, ap.telemetry.rejected)
    assert ap.telemetry.received["RangefinderReading"] > 50
    # used from its first readings below below_height_m: none inconsistent, jumped or tilted away
    assert not gate.rejected.keys() & {Rejection.INCONSISTENT, Rejection.NOT_DOWNWARD}, gate.rejected
    land = shell.config.mission.land_speed_m_s
    assert sink < 1.2 * land, sink  # met the ground at land speed (measured: 0.78 m/s, 0.76 m/s)
    assert 0.0 < decided_s < 6.0 and error < 1.0, (decided_s, error)
    print(f"{dialect} with: sink {sink:.2f} m/s, contact->touchdown {decided_s:.2f} s, error {error:.2f} m")


@pytest.mark.parametrize("dialect", ["ardupilot", "px4"])
async def test_without_the_rangefinder_the_drifted_estimate_meets_the_ground_fast(mav, udp_port, dialect):
    """The same flight on the estimate alone: the descent at v5 goes on down to the true 0.5-0.7 m
    and the vehicle meets the ground well above land speed; no DISTANCE_SENSOR asked for or used."""
    shell, ap, sink, decided_s, error = await _fly(mav, udp_port, dialect, rangefinder=False)
    assert shell.mission.rangefinder is None and "RangefinderReading" not in ap.telemetry.received
    land = shell.config.mission.land_speed_m_s
    assert sink > 1.5 * land, sink  # measured: 1.31 m/s (ArduPilot), 1.68 m/s (PX4)
    print(f"{dialect} without: sink {sink:.2f} m/s, contact->touchdown {decided_s:.2f} s, error {error:.2f} m")


async def test_a_noisy_rangefinder_is_gated_and_the_landing_goes_on(mav, udp_port):
    """SIM_SONAR_RND = 1.0 (ArduPilot's SITL noise, uniform within +-1 m): readings jump more than
    max_jump_m from one to the next; the gate rejects those, flies on the ones that agree or on the
    held correction, and the delivery lands as it would on the estimate."""
    params = {**PARAMS["ardupilot"], "SIM_SONAR_RND": 1.0}
    config = _config(mav, True)
    with mav.sim_vehicle(config, "ardupilot", udp_port, params=params) as sim:
        ap = ArduPilotAutopilot.from_config(config.model_copy(update={"connection": f"udpin:127.0.0.1:{udp_port}"}))
        shell, summary = await mav.fly(config, ap)
    assert summary.delivered, summary.failure
    gate = shell.mission.rangefinder
    # consecutive readings differ by more than 0.5 m more often than not: ~15 expected in the 3 s descent
    assert gate is not None and gate.rejected[Rejection.JUMP] >= 5, gate.rejected
    assert len(sim.vehicle.touchdowns) == 1
    print(f"noisy: used {gate.accepted}, rejected {dict(gate.rejected)}")
