"""The sitl_short delivery on real PX4 SIH over a serial link, as on a board (a Raspberry Pi UART on
TELEM2): companion_lab.serial_relay's two pty pairs, paced at 921600 baud (8N1) each way. Once the
SITL is up, a second MAVLink instance in onboard mode is started on the relay's autopilot side
through PX4's shell client (``px4-mavlink start -d DEVICE -b 921600 -m onboard``, what
``MAV_1_CONFIG = TELEM2`` does at boot on a board); the companion's MAVSDK opens
``serial://DEVICE:921600``. Ground truth is HIL_STATE_QUATERNION on the GCS link (udp 14550)."""

from __future__ import annotations

import asyncio
import subprocess
import time

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.config import shipped_params_path
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.px4_sitl import Px4Sitl
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.real_campaign import firmware_tuning
from companion_lab.serial_relay import SerialRelay, frame_summary
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.firmware

BAUD = 921600
SET_POSITION_TARGET_LOCAL_NED = 84  # MAVSDK's offboard velocity setpoints, timed on the line


def _start_serial_mavlink(sitl: Px4Sitl, device: str, baud: int) -> None:
    """A MAVLink instance on ``device`` in onboard mode at its default data rate (half the line,
    as MAV_1_RATE = 0), through the running SITL's shell client."""
    client = sitl.build_dir / "bin" / "px4-mavlink"
    cmd = [str(client), "--instance", str(sitl.instance), "start", "-d", device, "-b", str(baud), "-m", "onboard"]
    rootfs = sitl.build_dir / "rootfs" / str(sitl.instance)
    done = subprocess.run(cmd, cwd=rootfs, capture_output=True, text=True, timeout=20.0, check=False)
    assert done.returncode == 0, (cmd, done.stdout, done.stderr)


async def _overrun_once_linked(ap: Px4Autopilot, relay: SerialRelay) -> tuple[int, int]:
    """The overrun counts each way 1 s after the companion's link came up (MAVSDK reading)."""
    while not ap.link_ok:
        await asyncio.sleep(0.1)
    await asyncio.sleep(1.0)
    return relay.to_companion.overrun, relay.to_autopilot.overrun


async def test_px4_delivery_over_a_921600_baud_serial_link(px4_root, tmp_path):
    """Delivered and home over the serial link, the traffic within the line each way, and the
    setpoints at their 20 Hz with the line adding little to them."""
    tuning = firmware_tuning("px4")
    with (
        SerialRelay(baud=BAUD, seed=57, watch=(SET_POSITION_TARGET_LOCAL_NED,)) as relay,
        Px4Sitl(px4_root, log_path=tmp_path / "px4.log") as sitl,
        MavlinkTruth("udpin:127.0.0.1:14550") as truth,
    ):
        _start_serial_mavlink(sitl, relay.autopilot_device, BAUD)
        await asyncio.to_thread(truth.wait, 30.0)
        config = load_simulated_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                "autopilot": "px4",
                "connection": f"serial://{relay.companion_device}:{BAUD}",
                "mission": {**tuning["mission"], "return_home": True},
                "landing": tuning["landing"],
            },
        )
        ap = Px4Autopilot.from_config(config)
        rec = FlightRecorder(tmp_path / "run", config)
        down0, up0 = relay.to_companion.snapshot(), relay.to_autopilot.snapshot()
        t0 = time.monotonic()
        linked = asyncio.create_task(_overrun_once_linked(ap, relay))
        try:
            r = await fly_on_truth(config, ap, truth, truth.origin, (0.0, 0.0), timeout_s=240.0, recorder=rec)
        finally:
            # before the port closes: from then on nobody reads the companion's side
            seconds = time.monotonic() - t0
            down, up = relay.to_companion.snapshot(), relay.to_autopilot.snapshot()
            linked.cancel()
            rec.close()
            await ap.close()
    if not r.delivered or not r.returned:
        print(flight_story(tmp_path / "run", tmp_path / "px4.log"))
    down_bps, up_bps = (down.line - down0.line) / seconds, (up.line - up0.line) / seconds
    line = frame_summary(relay.frame_times("to_autopilot"), SET_POSITION_TARGET_LOCAL_NED)
    print(
        f"\nsetpoints on the line: {line.get('n', 0):.0f} timed, latency p50 {line.get('latency_p50_ms', 0):.2f} / "
        f"p99 {line.get('latency_p99_ms', 0):.2f} / max {line.get('latency_max_ms', 0):.2f} ms, interval "
        f"{line.get('interval_mean_ms', 0):.1f} +- {line.get('interval_std_ms', 0):.1f} ms (max "
        f"{line.get('interval_max_ms', 0):.0f}), the relay's own lag p99 {line.get('relay_lag_p99_ms', 0):.1f} ms"
    )
    print(
        f"\nPX4 {BAUD} baud: {seconds:.1f} s; autopilot -> companion {down_bps:.0f} B/s (peak second "
        f"{down.peak_bytes_per_s}), companion -> autopilot {up_bps:.0f} B/s (peak {up.peak_bytes_per_s}) of "
        f"{relay.bytes_per_s:.0f} B/s each way\n{relay.report()}\npad error on truth "
        f"{r.pad_landing_error_m * 100:.1f} cm, releases {r.releases}; failure {r.failure!r}"
    )
    assert r.delivered and r.returned, r.failure
    assert r.pad_landing_error_m < 0.3, r
    # one 65-byte frame is 0.7 ms at 921600: a setpoint waits at most a few frames for the line
    assert line and line["latency_p99_ms"] < 8.0 and line["interval_mean_ms"] < 55.0, line
    budget = relay.bytes_per_s
    # onboard mode's streams plus what MAVSDK asks for; PX4 keeps them under its data rate (half the line)
    assert 5000 < down_bps < 0.5 * budget, down_bps
    assert 500 < up_bps < 0.1 * budget, up_bps
    # the companion read everything once linked (before MAVSDK opened the port, PX4's streams
    # filled the pty's buffer and overran, as on a UART nobody reads)
    assert linked.done() and not linked.cancelled(), "the companion never linked"
    assert (down.overrun, up.overrun) == linked.result(), (down.overrun, up.overrun, linked.result())
