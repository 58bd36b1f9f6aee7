"""On the real firmware (PX4 v1.16 SIH, ArduCopter 4.7 SITL), one sitl_short flight through a UDP
relay that can cut the link (on ArduCopter the companion on SERIAL2), and a pilot: on PX4 a ground
station on PX4's GCS link, on ArduCopter the pilot's transmitter on the SITL's RC input.

1. the link drops for 3 s on the way out: the companion stops commanding (LINK_LOST); PX4's
   offboard-loss failsafe takes the vehicle out of OFFBOARD (COM_OF_LOSS_T), while ArduCopter stays
   in GUIDED and, GUID_TIMEOUT (3 s) after our last setpoint, stops; the link comes back and the
   mission resumes from where the vehicle is (LINK_RESTORED, on PX4 OFFBOARD again);
2. then the pilot switches to HOLD (PX4, a DO_SET_MODE from the ground station) or moves the
   flight-mode switch (channel 5) to LOITER (ArduCopter): autonomy ends, the companion never takes
   OFFBOARD / GUIDED back, the vehicle holds (PX4) or loiters (ArduCopter)."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from companion.autopilot.ardupilot.modes import COPTER_MODES
from companion.autopilot.types import FlightMode, LandedState
from companion.config import shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.events import EventKind, Phase
from companion_firmware.udp_relay import UdpRelay
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.firmware

MAV_CMD_DO_SET_MODE = 176
PX4_AUTO_LOITER = (1.0, 4.0, 3.0)  # base mode custom, PX4 main mode AUTO, sub mode LOITER ("Hold")
LOITER_PWM = 1685  # flight-mode switch position 5 (1621-1750 us): FLTMODE5 = 5, LOITER, in copter.parm
SITL_CH5_US = 1800  # the SITL's own RC default (position 6, STABILIZE): sent unchanged until the switch

# the mode the companion flies in, and the one the pilot switches to (PX4: FlightMode, ArduCopter:
# its mode number)
AUTONOMOUS = {"px4": FlightMode.OFFBOARD, "ardupilot": COPTER_MODES["GUIDED"]}
PILOTS = {"px4": FlightMode.HOLD, "ardupilot": COPTER_MODES["LOITER"]}
TIMEOUT_S = {"px4": 150.0, "ardupilot": 200.0}
ARM_TIMEOUT_S = {"ardupilot": 90.0}


def _config(name: str, port: int):
    tuning = firmware_tuning(name)
    if name == "px4":
        overrides = {"connection": f"udpin://127.0.0.1:{port}", "autopilot": "px4", **tuning}
    else:
        overrides = {
            "connection": f"udpin://127.0.0.1:{port}",
            "autopilot": "ardupilot",
            "mission": {**tuning["mission"], "ready_timeout_s": 120.0},  # EKF3 uses GPS ~41 s after boot
            "landing": tuning["landing"],
        }
    return load_simulated_config(shipped_params_path("sitl_short.toml"), overrides=overrides)


def _mode(name: str, shell: DeliveryShell) -> Any:
    """The vehicle's mode as the companion sees it (None: no status yet from PX4)."""
    if name == "px4":
        st = shell.autopilot.telemetry.status
        return st.mode if st is not None else None
    return getattr(shell.autopilot, "copter_mode", -1)


@contextlib.contextmanager
def _vehicle(name: str, root: Path, tmp_path: Path, port: int) -> Iterator[tuple[UdpRelay, Callable[[], Any]]]:
    """The started SITL behind the relay to the companion's ``port``: the relay and the pilot's switch
    (returns, on PX4, the future of the ground station's DO_SET_MODE; on ArduCopter the time of
    the RC switch)."""
    if name == "px4":
        from companion_firmware.px4_sitl import Px4Sitl
        from companion_firmware.truth_feed import MavlinkTruth

        relay = UdpRelay(14540, port)
        with Px4Sitl(root, log_path=tmp_path / "px4.log"), relay, MavlinkTruth("udpin:127.0.0.1:14550") as truth:
            truth.wait(30.0)
            yield (
                relay,
                lambda: asyncio.get_running_loop().run_in_executor(
                    None, truth.command, MAV_CMD_DO_SET_MODE, *PX4_AUTO_LOITER
                ),
            )
        return
    from companion_firmware.ardupilot_sitl import ArduCopterSitl
    from companion_firmware.dart_arducopter import RCIN_PORT, SitlRcInput

    relay_port = free_udp_port()
    relay = UdpRelay(relay_port, port)
    rc = SitlRcInput(RCIN_PORT)
    rc.set({1: 1500, 2: 1500, 3: 1000, 4: 1500, 5: SITL_CH5_US})

    def switch() -> float:
        rc.set({3: 1500})  # mid throttle first: LOITER's throttle is a climb rate
        return rc.set({5: LOITER_PWM})

    sitl = ArduCopterSitl(root, serials={2: f"udpclient:127.0.0.1:{relay_port}"}, log_path=tmp_path / "arducopter.log")
    rc.start()
    try:
        with relay, sitl:
            yield relay, switch
    finally:
        rc.stop()


def _autopilot(name: str, config: Any) -> Any:
    if name == "px4":
        from companion.autopilot.px4 import Px4Autopilot

        return Px4Autopilot.from_config(config)
    from companion.autopilot.ardupilot import ArduPilotAutopilot

    return ArduPilotAutopilot.from_config(config, arm_timeout_s=ARM_TIMEOUT_S[name])


async def test_link_loss_resumes_and_a_pilot_mode_switch_ends_autonomy(firmware, tmp_path):
    name, root = firmware
    auto = AUTONOMOUS[name]
    port = free_udp_port()
    config = _config(name, port)
    modes: list[tuple[float, Any]] = []
    state: dict = {"cut_at": None, "switch_at": None, "switch": None}

    with _vehicle(name, root, tmp_path, port) as (relay, switch):

        def tick(shell: DeliveryShell, out) -> None:
            now = time.monotonic()
            mode = _mode(name, shell)
            if mode is not None and (not modes or modes[-1][1] != mode):
                modes.append((now, mode))
            if out.phase is Phase.OUTBOUND and state["cut_at"] is None and shell.mission.sector >= 2:
                state["cut_at"] = now
                relay.cut(3.0)
            if name == "px4":  # the mission resumed: PX4 back in OFFBOARD, which its failsafe had left
                restored = EventKind.LINK_RESTORED in [e.kind for e in shell.events] and mode is auto
            else:  # ArduCopter never left GUIDED: the link's restoration after the cut
                restored = state["cut_at"] is not None and any(
                    e.kind is EventKind.LINK_RESTORED and e.time_s > state["cut_at"]
                    for e in shell.events  # loop time = monotonic
                )
            if restored and state["switch_at"] is None and now - state["cut_at"] > 8.0:
                if name == "px4":
                    state["switch_at"] = now
                    state["switch"] = switch()
                else:
                    state["switch_at"] = switch()

        ap = _autopilot(name, config)
        try:
            shell = DeliveryShell(config, ap, on_tick=tick)
            summary = await shell.run(timeout_s=TIMEOUT_S[name])
            kinds = [e.kind for e in shell.events]
            # 1. the link drop: noticed, the mission resumed when it came back
            assert EventKind.LINK_LOST in kinds and EventKind.LINK_RESTORED in kinds, kinds
            assert relay.dropped > 50
            if name == "px4":  # PX4's failsafe left OFFBOARD, OFFBOARD re-entered after it
                after_cut = [m for t, m in modes if t > state["cut_at"]]
                assert FlightMode.OFFBOARD in after_cut and after_cut[0] is not FlightMode.OFFBOARD, modes
            else:  # ArduCopter kept GUIDED (and stopped on GUID_TIMEOUT)
                during = [m for t, m in modes if state["cut_at"] <= t < state["cut_at"] + 3.0]
                assert all(m == COPTER_MODES["GUIDED"] for m in during), modes
            # 2. the pilot's switch ends autonomy, and the autonomous mode never comes back
            assert state["switch_at"] is not None, "the flight never resumed after the link drop"
            if name == "px4":  # the ground station's DO_SET_MODE is acknowledged (the RC switch has no ack)
                assert await state["switch"] == 0  # MAV_RESULT_ACCEPTED
            assert EventKind.PILOT_TAKEOVER in kinds, kinds
            assert summary.failure.startswith("pilot took over"), summary.failure
            assert shell.mission.phase is Phase.PILOT
            await asyncio.sleep(3.0)
            assert _mode(name, shell) == PILOTS[name]  # PX4 holds, ArduCopter loiters
            after = [m for t, m in modes if t > state["switch_at"] + 1.0]
            assert all(m != auto for m in after), modes
            if name == "px4":
                seen = [(round(t - state["cut_at"], 1), m.value) for t, m in modes if t > state["cut_at"]]
                print(f"\nmodes after the cut (s, mode): {seen}")
            else:
                seen = [(round(t - state["cut_at"], 1), m) for t, m in modes if t > state["cut_at"] - 1.0]
                print(f"\nArduCopter modes around the cut (s, mode number): {seen}")
            await ap.land()
            if name == "px4":  # PX4's test waited for the landing (up to 40 s), ArduCopter's did not
                t_end = time.monotonic() + 40.0
                while ap.telemetry.status.landed is not LandedState.ON_GROUND and time.monotonic() < t_end:
                    await asyncio.sleep(0.2)
        finally:
            await ap.close()
