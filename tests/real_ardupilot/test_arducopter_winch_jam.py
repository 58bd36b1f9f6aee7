"""A winch that will not reel in, against a real ArduCopter SITL (docs/winch.md#a-line-that-will-not-reel-in):
AP_Winch's PWM backend on output 10, the servo gripper on output 9, winch.reel_check_s on.

ArduCopter's SITL simulates no winch: the PWM backend's line length is the integral of the rate it
commands, so no SITL parameter jams its line. The stand-in is the winch's own speed limit:
WINCH_RATE_MAX set to 0 once the release is under way, so the firmware's length control really does
not reel in (its WINCH_STATUS line stays out). The companion must say the jam, not fly the line
home, and the firmware must land where the vehicle hovers and disarm. The shortest flight that
shows it: the pad 4 m from home, a 2 m hover, the line at 1 m/s, no retry."""

from __future__ import annotations

import asyncio
import contextlib
import csv
import math

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.config import shipped_params_path
from companion.delivery.winch import WinchStep
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import load_simulated_config

from .conftest import GRIPPER_SERVO9, wait_for

pytestmark = pytest.mark.firmware

WINCH_SERVO10 = {"WINCH_TYPE": 1, "SERVO10_FUNCTION": 88, "WINCH_RATE_MAX": 1.0, "WINCH_POS_P": 1.0}
MAV_CMD_SET_MESSAGE_INTERVAL = 511
WINCH_STATUS = 9005


async def test_arducopter_winch_that_will_not_reel_in_lands_where_it_hovers(ardupilot_root, tmp_path):
    tuning = firmware_tuning("ardupilot")
    truth_port = free_udp_port()
    sitl = ArduCopterSitl(
        ardupilot_root,
        extra_params={**GRIPPER_SERVO9, **WINCH_SERVO10},
        serials={1: f"udpclient:127.0.0.1:{truth_port}"},
        log_path=tmp_path / "arducopter.log",
    )
    truth = MavlinkTruth(f"udpin:127.0.0.1:{truth_port}", message="SIM_STATE", watch=("WINCH_STATUS", "HEARTBEAT"))
    with sitl, truth:
        await asyncio.to_thread(truth.wait, 15.0)
        await asyncio.to_thread(truth.command, MAV_CMD_SET_MESSAGE_INTERVAL, WINCH_STATUS, 200_000)
        config = load_simulated_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                "autopilot": "ardupilot",
                "connection": sitl.connection,
                "mission": {
                    **tuning["mission"],
                    "ready_timeout_s": 120.0,
                    "delivery": "winch",
                    "height_m": 5.0,
                    "pad": {"north_m": 3.0, "east_m": 3.0, "size_m": 1.0},
                },
                "landing": tuning["landing"],
                "winch": {
                    "hover_height_m": 2.0,
                    "payout_rate_m_s": 1.0,
                    "reel_rate_m_s": 1.0,
                    "settle_s": 1.0,
                    "reel_check_s": 1.0,
                    "reel_retries": 0,
                },
            },
        )
        ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
        rec = FlightRecorder(tmp_path / "run", config)
        shells: list = []
        jammed_at: list[float] = []
        track: list[tuple[float, float]] = []  # (monotonic s, true height above the start m)

        async def jam_the_winch() -> None:
            """At the release: the winch's speed limit to 0 on the firmware (the reel-in cannot move)."""
            ground_pd = truth.pd
            while True:
                await asyncio.sleep(0.1)
                track.append((asyncio.get_running_loop().time(), ground_pd - truth.pd))
                seq = shells[0].mission.winch if shells else None
                if not jammed_at and seq is not None and seq.step_now is WinchStep.RELEASE:
                    await asyncio.to_thread(truth.set_param, "WINCH_RATE_MAX", 0.0)
                    jammed_at.append(asyncio.get_running_loop().time())

        jammer = asyncio.get_running_loop().create_task(jam_the_winch())
        try:
            r = await fly_on_truth(
                config, ap, truth, truth.origin, (0.0, 0.0), timeout_s=120.0, recorder=rec, on_shell=shells.append
            )
        finally:
            jammer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await jammer
            rec.close()
            await ap.close()
        lines = [m.line_length for _, m in truth.watched_messages("WINCH_STATUS")]
        # disarmed on the ground (MAV_MODE_FLAG_SAFETY_ARMED clear): the heartbeat on this link is 1 Hz
        await wait_for(lambda: not truth.watched_messages("HEARTBEAT")[-1][1].base_mode & 128, 3.0, "disarmed")
    with (tmp_path / "run" / "events.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    events = [(row["kind"], row["phase"], row["detail"]) for row in rows]
    stamps = [(float(row["time_s"]), row["phase"] if row["kind"] == "phase" else row["kind"]) for row in rows]
    after = [h for t, h in track if jammed_at and t >= jammed_at[0]]
    print(
        "\n"
        + "\n".join(f"{k} {ph}: {d}" for k, ph, d in events if k in ("winch", "winch_jam", "released", "phase"))
        + f"\nWINCH_STATUS line {min(lines, default=math.nan):.2f}-{max(lines, default=math.nan):.2f} m, "
        f"last {lines[-1] if lines else math.nan:.2f} m; jammed {bool(jammed_at)}; r.failure {r.failure!r}"
        + "".join(f"\n{t:.2f} s {k}" for t, k in stamps if k in ("released", "winch_jam", "abort_land", "failed"))
        + f"\ntrue height from the jam: {after[0] if after else math.nan:.2f} m, "
        f"at most {max(after, default=math.nan):.2f}, last {after[-1] if after else math.nan:.2f}"
    )
    if not jammed_at or r.returned:
        print(flight_story(tmp_path / "run", tmp_path / "arducopter.log"))
    assert jammed_at, "the release never started"
    kinds = [(k, ph) for k, ph, _ in events]
    jam = kinds.index(("winch_jam", "winch"))
    assert jam < kinds.index(("phase", "abort_land")), events  # said first
    assert ("phase", "inbound") not in kinds and not r.returned  # the line never flown home
    assert r.failure == "aborted: the line will not reel in after 1 try", r.failure
    # the firmware's own line: out to the hover height, and still out on the ground
    assert max(lines) > 2.0 and lines[-1] > 2.0, lines[-5:]
    # no climb with the line out, then down to the ground where it hovered
    assert max(after) < after[0] + 0.5 and after[-1] < 0.3, (after[0], max(after), after[-1])
