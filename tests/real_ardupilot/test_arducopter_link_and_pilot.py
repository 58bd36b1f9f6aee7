"""On the real ArduCopter 4.7 SITL, one sitl_short flight with the companion on SERIAL2 through a
UDP relay that can cut the link, and the pilot's transmitter on the SITL's RC input:

1. the link drops for 3 s on the way out: the companion stops commanding (LINK_LOST); ArduCopter
   stays in GUIDED and, GUID_TIMEOUT (3 s) after our last setpoint, stops; the link comes back and
   the mission resumes from where the vehicle is (LINK_RESTORED);
2. then the pilot moves the flight-mode switch (channel 5) to LOITER: autonomy ends, the
   companion never takes GUIDED back, ArduCopter loiters."""

from __future__ import annotations

import asyncio
import time

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.modes import COPTER_MODES
from companion.config import shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.events import EventKind, Phase
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_firmware.dart_arducopter import RCIN_PORT, SitlRcInput
from companion_firmware.udp_relay import UdpRelay
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.firmware

LOITER_PWM = 1685  # flight-mode switch position 5 (1621-1750 us): FLTMODE5 = 5, LOITER, in copter.parm
SITL_CH5_US = 1800  # the SITL's own RC default (position 6, STABILIZE): sent unchanged until the switch


async def test_link_loss_resumes_and_the_pilots_mode_switch_ends_autonomy(ardupilot_root, tmp_path):
    relay_port, port = free_udp_port(), free_udp_port()
    tuning = firmware_tuning("ardupilot")
    config = load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "connection": f"udpin://127.0.0.1:{port}",
            "autopilot": "ardupilot",
            "mission": {**tuning["mission"], "ready_timeout_s": 120.0},  # EKF3 uses GPS ~41 s after boot
            "landing": tuning["landing"],
        },
    )
    modes: list[tuple[float, int]] = []
    state: dict = {"cut_at": None, "switch_at": None}
    relay = UdpRelay(relay_port, port)
    rc = SitlRcInput(RCIN_PORT)
    rc.set({1: 1500, 2: 1500, 3: 1000, 4: 1500, 5: SITL_CH5_US})

    def tick(shell: DeliveryShell, out) -> None:
        now = time.monotonic()
        mode = getattr(shell.autopilot, "copter_mode", -1)
        if not modes or modes[-1][1] != mode:
            modes.append((now, mode))
        if out.phase is Phase.OUTBOUND and state["cut_at"] is None and shell.mission.sector >= 2:
            state["cut_at"] = now
            relay.cut(3.0)
        restored = state["cut_at"] is not None and any(
            e.kind is EventKind.LINK_RESTORED and e.time_s > state["cut_at"]
            for e in shell.events  # loop time = monotonic
        )
        if restored and state["switch_at"] is None and now - state["cut_at"] > 8.0:
            rc.set({3: 1500})  # mid throttle first: LOITER's throttle is a climb rate
            state["switch_at"] = rc.set({5: LOITER_PWM})

    sitl = ArduCopterSitl(
        ardupilot_root, serials={2: f"udpclient:127.0.0.1:{relay_port}"}, log_path=tmp_path / "arducopter.log"
    )
    rc.start()
    try:
        with relay, sitl:
            ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=90.0)
            try:
                shell = DeliveryShell(config, ap, on_tick=tick)
                summary = await shell.run(timeout_s=200.0)
                kinds = [e.kind for e in shell.events]
                # 1. the link drop: noticed, the vehicle kept GUIDED (and stopped on GUID_TIMEOUT),
                #    the mission resumed when it came back
                assert EventKind.LINK_LOST in kinds and EventKind.LINK_RESTORED in kinds, kinds
                assert relay.dropped > 50
                during = [m for t, m in modes if state["cut_at"] <= t < state["cut_at"] + 3.0]
                assert all(m == COPTER_MODES["GUIDED"] for m in during), modes
                # 2. the pilot's LOITER ends autonomy, and GUIDED never comes back
                assert state["switch_at"] is not None, "the flight never resumed after the link drop"
                assert EventKind.PILOT_TAKEOVER in kinds, kinds
                assert summary.failure.startswith("pilot took over"), summary.failure
                assert shell.mission.phase is Phase.PILOT
                await asyncio.sleep(3.0)
                assert ap.copter_mode == COPTER_MODES["LOITER"]
                after = [m for t, m in modes if t > state["switch_at"] + 1.0]
                assert all(m != COPTER_MODES["GUIDED"] for m in after), modes
                seen = [(round(t - state["cut_at"], 1), m) for t, m in modes if t > state["cut_at"] - 1.0]
                print(f"\nArduCopter modes around the cut (s, mode number): {seen}")
                await ap.land()
            finally:
                await ap.close()
    finally:
        rc.stop()
