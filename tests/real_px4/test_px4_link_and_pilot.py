"""On the real PX4 v1.16 SIH, one sitl_short flight through a UDP relay that can cut the link:

1. the link drops for 3 s on the way out: the companion stops commanding (LINK_LOST), PX4's
   offboard-loss failsafe takes the vehicle out of OFFBOARD (COM_OF_LOSS_T), the link comes back
   and the mission resumes from where the vehicle is (LINK_RESTORED, OFFBOARD again);
2. then the pilot (here a ground station on PX4's GCS link) switches to HOLD: autonomy ends, the
   companion never takes OFFBOARD back, PX4 holds."""

from __future__ import annotations

import asyncio
import time

import pytest

from companion.autopilot.types import FlightMode, LandedState
from companion.config import shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.events import EventKind, Phase
from companion_firmware.px4_sitl import Px4Sitl
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.udp_relay import UdpRelay
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.firmware

MAV_CMD_DO_SET_MODE = 176
PX4_AUTO_LOITER = (1.0, 4.0, 3.0)  # base mode custom, PX4 main mode AUTO, sub mode LOITER ("Hold")


async def test_link_loss_resumes_and_a_pilot_mode_switch_ends_autonomy(px4_root, tmp_path):
    port = free_udp_port()
    tuning = firmware_tuning("px4")
    config = load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={"connection": f"udpin://127.0.0.1:{port}", "autopilot": "px4", **tuning},
    )
    from companion.autopilot.px4 import Px4Autopilot

    modes: list[tuple[float, FlightMode]] = []
    state: dict = {"cut_at": None, "switch_at": None, "switch": None}
    relay = UdpRelay(14540, port)

    def tick(shell: DeliveryShell, out) -> None:
        st = shell.autopilot.telemetry.status
        now = time.monotonic()
        if st is not None and (not modes or modes[-1][1] is not st.mode):
            modes.append((now, st.mode))
        if out.phase is Phase.OUTBOUND and state["cut_at"] is None and shell.mission.sector >= 2:
            state["cut_at"] = now
            relay.cut(3.0)
        kinds = [e.kind for e in shell.events]
        if (
            EventKind.LINK_RESTORED in kinds
            and state["switch_at"] is None
            and st is not None
            and st.mode is FlightMode.OFFBOARD
            and now - state["cut_at"] > 8.0
        ):
            state["switch_at"] = now
            state["switch"] = asyncio.get_running_loop().run_in_executor(
                None, truth.command, MAV_CMD_DO_SET_MODE, *PX4_AUTO_LOITER
            )

    with Px4Sitl(px4_root, log_path=tmp_path / "px4.log"), relay, MavlinkTruth("udpin:127.0.0.1:14550") as truth:
        await asyncio.to_thread(truth.wait, 30.0)
        ap = Px4Autopilot.from_config(config)
        try:
            shell = DeliveryShell(config, ap, on_tick=tick)
            summary = await shell.run(timeout_s=150.0)
            kinds = [e.kind for e in shell.events]
            # 1. the link drop: noticed, PX4's failsafe left OFFBOARD, OFFBOARD re-entered after it
            assert EventKind.LINK_LOST in kinds and EventKind.LINK_RESTORED in kinds, kinds
            assert relay.dropped > 50
            after_cut = [m for t, m in modes if t > state["cut_at"]]
            assert FlightMode.OFFBOARD in after_cut and after_cut[0] is not FlightMode.OFFBOARD, modes
            # 2. the pilot's HOLD ends autonomy, and OFFBOARD never comes back
            assert state["switch_at"] is not None, "the flight never resumed after the link drop"
            assert await state["switch"] == 0  # MAV_RESULT_ACCEPTED
            assert EventKind.PILOT_TAKEOVER in kinds, kinds
            assert summary.failure.startswith("pilot took over"), summary.failure
            assert shell.mission.phase is Phase.PILOT
            await asyncio.sleep(3.0)
            assert ap.telemetry.status.mode is FlightMode.HOLD
            assert all(m is not FlightMode.OFFBOARD for t, m in modes if t > state["switch_at"] + 1.0), modes
            seen = [(round(t - state["cut_at"], 1), m.value) for t, m in modes if t > state["cut_at"]]
            print(f"\nmodes after the cut (s, mode): {seen}")
            await ap.land()
            t_end = time.monotonic() + 40.0
            while ap.telemetry.status.landed is not LandedState.ON_GROUND and time.monotonic() < t_end:
                await asyncio.sleep(0.2)
        finally:
            await ap.close()
