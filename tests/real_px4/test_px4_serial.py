"""The sitl_short delivery on real PX4 SIH over a serial link, as on a board (a Raspberry Pi UART on
TELEM2): companion_lab.serial_relay's two pty pairs, paced at 921600 or 115200 baud (8N1) each way,
in the last test dropping and corrupting bytes. Once the SITL is up, a second MAVLink instance in
onboard mode is started on the relay's autopilot side through PX4's shell client
(``px4-mavlink start -d DEVICE -b BAUD -m onboard``, what ``MAV_1_CONFIG = TELEM2`` does at boot on
a board); the companion's MAVSDK opens ``serial://DEVICE:BAUD``. Ground truth is
HIL_STATE_QUATERNION on the GCS link (udp 14550). docs/serial-link.md has the figures."""

from __future__ import annotations

import asyncio
import subprocess
import time
from pathlib import Path

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.config import shipped_params_path
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.px4_sitl import Px4Sitl
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import HarnessResult, flight_story, fly_on_truth
from companion_lab.real_campaign import firmware_tuning
from companion_lab.serial_relay import SerialRelay, frame_summary
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.firmware

BAUD = 921600
SET_POSITION_TARGET_LOCAL_NED = 84  # MAVSDK's offboard velocity setpoints, timed on the line
PAD_HALF_SIZE_M = 0.5  # the pad is 1 m square: a release farther from its centre is off the pad


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


async def _fly_px4_serial(
    px4_root: Path, tmp_path: Path, baud: int, overlays: tuple[str, ...] = (), drop: float = 0.0, corrupt: float = 0.0
) -> tuple[HarnessResult, Px4Autopilot, SerialRelay, tuple[float, float], dict[str, float], tuple[int, int]]:
    """Fly the delivery over the relay; the result, the backend, the relay, the bytes/s each way
    over the flight, the setpoints on the line (the relay's frame_summary), and the overruns
    each way since the companion linked against those at 1 s after it did."""
    tuning = firmware_tuning("px4")
    relay = SerialRelay(baud=baud, drop=drop, corrupt=corrupt, seed=57, watch=(SET_POSITION_TARGET_LOCAL_NED,))
    with (
        relay,
        Px4Sitl(px4_root, log_path=tmp_path / "px4.log") as sitl,
        MavlinkTruth("udpin:127.0.0.1:14550") as truth,
    ):
        _start_serial_mavlink(sitl, relay.autopilot_device, baud)
        await asyncio.to_thread(truth.wait, 30.0)
        config = load_simulated_config(
            *(shipped_params_path(f) for f in ("sitl_short.toml", *overlays)),
            overrides={
                "autopilot": "px4",
                "connection": f"serial://{relay.companion_device}:{baud}",
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
    rates = ((down.line - down0.line) / seconds, (up.line - up0.line) / seconds)
    line = frame_summary(relay.frame_times("to_autopilot"), SET_POSITION_TARGET_LOCAL_NED)
    print(
        f"\nsetpoints on the line: {line.get('n', 0):.0f} timed, latency p50 {line.get('latency_p50_ms', 0):.2f} / "
        f"p99 {line.get('latency_p99_ms', 0):.2f} / max {line.get('latency_max_ms', 0):.2f} ms, interval "
        f"{line.get('interval_mean_ms', 0):.1f} +- {line.get('interval_std_ms', 0):.1f} ms (max "
        f"{line.get('interval_max_ms', 0):.0f}), the relay's own lag p99 {line.get('relay_lag_p99_ms', 0):.1f} ms"
    )
    print(
        f"\nPX4 {baud} baud: {seconds:.1f} s; autopilot -> companion {rates[0]:.0f} B/s (peak second "
        f"{down.peak_bytes_per_s}), companion -> autopilot {rates[1]:.0f} B/s (peak {up.peak_bytes_per_s}) of "
        f"{relay.bytes_per_s:.0f} B/s each way\n{relay.report()}\npad error on truth "
        f"{r.pad_landing_error_m * 100:.1f} cm, releases {r.releases}; failure {r.failure!r}"
    )
    assert linked.done() and not linked.cancelled(), "the companion never linked"
    overruns = ((down.overrun, up.overrun), linked.result())
    return r, ap, relay, rates, line, overruns  # type: ignore[return-value]


async def test_px4_delivery_over_a_921600_baud_serial_link(px4_root, tmp_path):
    """Delivered and home over the serial link, the traffic within the line each way, and the
    setpoints at their 20 Hz with the line adding little to them."""
    r, _ap, relay, (down_bps, up_bps), line, (overrun, overrun_linked) = await _fly_px4_serial(px4_root, tmp_path, BAUD)
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
    assert overrun == overrun_linked, (overrun, overrun_linked)


async def test_px4_delivery_over_a_115200_baud_serial_link_with_its_stream_rates(px4_root, tmp_path):
    """At 115200 baud (11520 bytes/s each way) with params/serial_115200.toml, PX4's onboard
    instance at its default data rate (half the line): delivered and home, the downlink within
    PX4's data rate, setpoints still at 20 Hz behind what else is on the line."""
    r, _ap, relay, (down_bps, up_bps), line, (overrun, overrun_linked) = await _fly_px4_serial(
        px4_root, tmp_path, 115200, overlays=("serial_115200.toml",)
    )
    assert r.delivered and r.returned, r.failure
    assert r.pad_landing_error_m < 0.3, r
    # a 65-byte frame takes 5.6 ms at 115200
    assert line and line["latency_p99_ms"] < 60.0 and line["interval_mean_ms"] < 55.0, line
    budget = relay.bytes_per_s
    assert 1500 < down_bps < 0.55 * budget, down_bps  # PX4's data rate: half the line (MAV_x_RATE = 0)
    assert 500 < up_bps < 0.25 * budget, up_bps
    assert overrun == overrun_linked, (overrun, overrun_linked)


async def test_px4_over_a_serial_link_losing_and_corrupting_a_tenth_of_a_percent_of_its_bytes(px4_root, tmp_path):
    """At 921600 baud, 0.05 % of the bytes dropped and 0.05 % corrupted each way (seeded), as the
    ArduCopter test does through pymavlink; here MAVSDK parses the companion's side. The end is
    safe whichever way it comes (delivered and home, or no release off the pad), the relay counts
    the faults at their fraction."""
    r, _ap, relay, _rates, line, _overruns = await _fly_px4_serial(
        px4_root, tmp_path, BAUD, drop=0.0005, corrupt=0.0005
    )
    for st in (relay.to_companion, relay.to_autopilot):
        faults = st.dropped + st.corrupted
        assert st.dropped > 0 and st.corrupted > 0, st
        assert 0.0006 < faults / st.line < 0.0014, (st.name, faults, st.line)
    if r.releases:
        assert r.pad_landing_error_m < PAD_HALF_SIZE_M, r
    assert r.delivered and r.returned, r.failure
    assert line and line["interval_mean_ms"] < 60.0, line  # the stream goes on (a few % of frames lost)
