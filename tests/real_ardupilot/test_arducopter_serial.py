"""The sitl_short delivery on real ArduCopter SITL over a serial link, as on a board: a Raspberry
Pi's UART wired to the autopilot's TELEM2 (SERIAL2, MAVLink 2). The wire is
companion_lab.serial_relay: two pty pairs and a relay that paces each direction at the baud rate
(8N1: 10 bits a byte), counts the bytes and, in the last test, drops and corrupts 1 % of them. The
SITL opens its side as ``--serial2 uart:DEVICE:BAUD``, the companion ``serial://DEVICE:BAUD``
(pymavlink on pyserial). Ground truth comes as SIM_STATE on SERIAL1 (udp), the pad lies 1.5 m
from its configured position, the gripper is on output 9. docs/serial-link.md has the figures."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.config import shipped_params_path
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import HarnessResult, flight_story, fly_on_truth
from companion_lab.real_campaign import firmware_tuning
from companion_lab.serial_relay import DirectionStats, SerialRelay, frame_summary
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import load_simulated_config

from .conftest import GRIPPER_SERVO9

pytestmark = pytest.mark.firmware

PAD_OFFSET = (1.2, -0.9)  # 1.5 m: GPS alone would land 1.5 m off the true pad
SERIAL_PORT = 2  # TELEM2
SET_POSITION_TARGET_LOCAL_NED = 84  # the setpoints, timed on the line
# the pad is 1 m square: a release farther than this from its centre is off the pad
PAD_HALF_SIZE_M = 0.5


@contextlib.contextmanager
def _arducopter_on_serial(
    root: Path, log_dir: Path, relay: SerialRelay
) -> Iterator[tuple[ArduCopterSitl, MavlinkTruth]]:
    """One SITL (clean eeprom) with SERIAL2 on the relay's autopilot side at its baud rate
    (SERIAL2_BAUD in kbaud, as ArduPilot takes it) and SIM_STATE truth on SERIAL1."""
    port = free_udp_port()
    params = {
        **GRIPPER_SERVO9,
        f"SERIAL{SERIAL_PORT}_PROTOCOL": 2,  # MAVLink 2
        f"SERIAL{SERIAL_PORT}_BAUD": relay.baud // 1000,  # 921 or 115
    }
    sitl = ArduCopterSitl(
        root,
        extra_params=params,
        serials={1: f"udpclient:127.0.0.1:{port}", SERIAL_PORT: f"uart:{relay.autopilot_device}:{relay.baud}"},
        log_path=log_dir / "arducopter.log",
    )
    with sitl, MavlinkTruth(f"udpin:127.0.0.1:{port}", message="SIM_STATE") as feed:
        feed.wait(15.0)
        yield sitl, feed


async def _count_setpoints(ap: ArduPilotAutopilot, samples: list[tuple[float, int]]) -> None:
    """(time, setpoints sent) every 0.25 s, for the rate while the stream runs."""
    while True:
        samples.append((time.monotonic(), ap.counters.setpoints_sent))
        await asyncio.sleep(0.25)


def _streaming_rate(samples: list[tuple[float, int]]) -> float:
    """Setpoints per second from the first sample that saw one to the last that saw a new one."""
    moving = [(t, n) for (t, n), (_, prev) in zip(samples[1:], samples, strict=False) if n > prev]
    if len(moving) < 2:
        return 0.0
    (t0, n0), (t1, n1) = moving[0], moving[-1]
    return (n1 - n0) / (t1 - t0)


def _rate(before: DirectionStats, after: DirectionStats, seconds: float) -> float:
    return (after.line - before.line) / seconds


async def _fly_serial(
    ardupilot_root,
    tmp_path,
    baud: int,
    overlays: tuple[str, ...] = (),
    drop: float = 0.0,
    corrupt: float = 0.0,
    ready_timeout_s: float = 120.0,
):
    """Fly the delivery over the relay; the result, the autopilot (its counters), the relay, the
    bytes/s each way over the flight (from connect to the end), and the setpoints/s while they flowed
    with the setpoints' latency and intervals on the line (the relay's frame_summary)."""
    relay = SerialRelay(baud=baud, drop=drop, corrupt=corrupt, seed=57, watch=(SET_POSITION_TARGET_LOCAL_NED,))
    with relay, _arducopter_on_serial(ardupilot_root, tmp_path, relay) as (_sitl, truth):
        tuning = firmware_tuning("ardupilot")
        connection = f"serial://{relay.companion_device}:{baud}"
        overrides = {
            "autopilot": "ardupilot",
            "connection": connection,
            "mission": {**tuning["mission"], "ready_timeout_s": ready_timeout_s},
            "landing": tuning["landing"],
        }
        files = [shipped_params_path(f) for f in ("sitl_short.toml", *overlays)]
        config = load_simulated_config(*files, overrides=overrides)
        ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
        rec = FlightRecorder(tmp_path / "run", config)
        down0, up0 = relay.to_companion.snapshot(), relay.to_autopilot.snapshot()
        t0 = time.monotonic()
        samples: list[tuple[float, int]] = []
        counting = asyncio.create_task(_count_setpoints(ap, samples))
        try:
            r = await fly_on_truth(config, ap, truth, truth.origin, PAD_OFFSET, timeout_s=240.0, recorder=rec)
        finally:
            # before the port closes: from then on nobody reads the companion's side
            seconds = time.monotonic() - t0
            down, up = relay.to_companion.snapshot(), relay.to_autopilot.snapshot()
            counting.cancel()
            rec.close()
            await ap.close()
    if not r.delivered or not r.returned:
        print(flight_story(tmp_path / "run", tmp_path / "arducopter.log"))
    rates = (_rate(down0, down, seconds), _rate(up0, up, seconds))
    setpoint_hz = _streaming_rate(samples)
    line = frame_summary(relay.frame_times("to_autopilot"), SET_POSITION_TARGET_LOCAL_NED)
    print(
        f"\n{baud} baud: {seconds:.1f} s; autopilot -> companion {rates[0]:.0f} B/s (peak second "
        f"{down.peak_bytes_per_s}), companion -> autopilot {rates[1]:.0f} B/s (peak {up.peak_bytes_per_s}) "
        f"of {relay.bytes_per_s:.0f} B/s each way; setpoints {setpoint_hz:.1f}/s; "
        f"backlog max {down.max_backlog} / {up.max_backlog} bytes\n{relay.report()}\n"
        f"setpoints on the line: {_line_text(line)}\n"
        f"link: bad data {ap.counters.bad_data} ({ap.counters.garbage_bytes} bytes), messages "
        f"{ap.counters.messages}; pad error on truth {r.pad_landing_error_m * 100:.1f} cm, releases {r.releases}; "
        f"failure {r.failure!r}"
    )
    # the companion read everything while it flew (overrun: bytes its side did not take in time)
    overrun = (down.overrun - down0.overrun, up.overrun - up0.overrun)
    return r, ap, relay, rates, (setpoint_hz, line), overrun


def _line_text(s: dict[str, float]) -> str:
    if not s:
        return "none timed"
    return (
        f"{s['n']:.0f} timed, latency p50 {s['latency_p50_ms']:.2f} / p99 {s['latency_p99_ms']:.2f} / max "
        f"{s['latency_max_ms']:.2f} ms, interval {s['interval_mean_ms']:.1f} +- {s['interval_std_ms']:.1f} ms "
        f"(max {s['interval_max_ms']:.0f}; {s['pauses']:.0f} pauses > 0.5 s), the relay's own lag p99 "
        f"{s['relay_lag_p99_ms']:.1f} / max {s['relay_lag_max_ms']:.1f} ms"
    )


def _assert_delivered(r: HarnessResult) -> None:
    assert r.delivered and r.returned, r.failure
    assert r.pad_landing_error_m < 0.15, r  # the fused descent onto the displaced pad (tcp: 2.4 cm)


async def test_delivery_over_a_921600_baud_serial_link(ardupilot_root, tmp_path):
    """The whole delivery with the default streams (ATTITUDE and HIGHRES_IMU at 50 Hz, the
    positions at 30 Hz) and 20 Hz setpoints over TELEM2 at 921600 baud: delivered and home, every
    byte intact, and the traffic a small share of the line each way."""
    r, ap, relay, (down_bps, up_bps), (setpoint_hz, line), overrun = await _fly_serial(ardupilot_root, tmp_path, 921600)
    _assert_delivered(r)
    # a 65-byte frame takes 0.7 ms at 921600; the line adds at most a few frames' wait to a setpoint
    # (measured p50 0.71, p99 1.87, max 5.5 ms)
    assert line["latency_p99_ms"] < 8.0 and line["interval_mean_ms"] < 55.0, line
    assert ap.releases_unconfirmed == 0
    budget = relay.bytes_per_s  # 92160 bytes/s each way
    # the requested streams did flow: 50 Hz ATTITUDE alone is 2000 B/s, 20 Hz setpoints 1260 B/s
    assert 4000 < down_bps < 0.25 * budget, down_bps
    assert 1000 < up_bps < 0.05 * budget, up_bps
    assert relay.to_companion.peak_bytes_per_s < 0.25 * budget
    assert 18.5 < setpoint_hz < 22.5, setpoint_hz  # a 20 Hz stream: 19.8-21.2 /s counted
    assert overrun == (0, 0), overrun
    assert ap.counters.bad_data == 0  # a clean line: every byte parsed


async def test_delivery_over_a_115200_baud_serial_link_with_its_stream_rates(ardupilot_root, tmp_path):
    """At 115200 baud (11520 bytes/s) the default streams would take most of the line; with
    params/serial_115200.toml (attitude and IMU at 20 Hz, positions at 10 Hz) the delivery flies
    within half of it, setpoints still at 20 Hz."""
    r, _ap, relay, (down_bps, up_bps), (setpoint_hz, line), overrun = await _fly_serial(
        ardupilot_root, tmp_path, 115200, overlays=("serial_115200.toml",)
    )
    _assert_delivered(r)
    # a 65-byte frame takes 5.6 ms at 115200: the setpoint waits only behind what is on the line
    # (measured p50 5.6, p99 27, max 39 ms)
    assert line["latency_p99_ms"] < 60.0 and line["interval_mean_ms"] < 55.0, line
    budget = relay.bytes_per_s  # 11520 bytes/s each way
    assert 1500 < down_bps < 0.5 * budget, down_bps
    assert relay.to_companion.peak_bytes_per_s < 0.6 * budget
    assert 1000 < up_bps < 0.2 * budget, up_bps
    assert 18.5 < setpoint_hz < 22.5, setpoint_hz  # a 20 Hz stream: 19.8-21.2 /s counted
    assert overrun == (0, 0), overrun


async def test_a_serial_link_losing_and_corrupting_a_tenth_of_a_percent_of_its_bytes(ardupilot_root, tmp_path):
    """At 921600 baud, 0.05 % of the bytes dropped and 0.05 % corrupted each way (seeded): about
    one frame in 25 lost either way. The delivery flies and comes home; the relay counts the
    faults at their fraction and the companion's link the garbage it skipped."""
    r, ap, relay, _rates, (setpoint_hz, _line), _overrun = await _fly_serial(
        ardupilot_root, tmp_path, 921600, drop=0.0005, corrupt=0.0005
    )
    for st in (relay.to_companion, relay.to_autopilot):
        faults = st.dropped + st.corrupted
        assert st.dropped > 0 and st.corrupted > 0, st
        assert 0.0006 < faults / st.line < 0.0014, (st.name, faults, st.line)
    assert ap.counters.bad_data > 10 and ap.counters.garbage_bytes > 100, ap.counters
    _assert_delivered(r)
    assert setpoint_hz > 18.5  # the 20 Hz stream goes on (about 4 % of its frames are lost on the line)


async def test_a_serial_link_losing_one_percent_of_its_bytes_keeps_the_parcel_aboard(ardupilot_root, tmp_path):
    """At 921600 baud, 0.5 % of the bytes dropped and 0.5 % corrupted each way: about a third of
    the frames lost either way. The end must be safe: delivered and home, or no release off the
    pad (measured: the vehicle is not ready within the ready timeout, 30 s here, and the flight
    ends on the ground with the parcel aboard); the link's counters are full of the garbage."""
    r, ap, relay, _rates, _hz, _overrun = await _fly_serial(
        ardupilot_root, tmp_path, 921600, drop=0.005, corrupt=0.005, ready_timeout_s=30.0
    )
    for st in (relay.to_companion, relay.to_autopilot):
        faults = st.dropped + st.corrupted
        assert st.dropped > 0 and st.corrupted > 0, st
        assert 0.007 < faults / st.line < 0.013, (st.name, faults, st.line)
    assert ap.counters.bad_data > 100 and ap.counters.garbage_bytes > 1000, ap.counters
    # the end is safe whichever way it comes: home with the parcel, or a release only on the pad
    if r.delivered:
        assert r.returned, r.failure
    if r.releases:
        assert r.pad_landing_error_m < PAD_HALF_SIZE_M, r
    else:
        assert not r.delivered


async def test_preflight_states_the_link_budget_of_a_115200_baud_line(ardupilot_root, tmp_path):
    """`preflight` on the real SITL over the 115200 line: its `link budget` row measures the bytes
    each way as the relay counts them; the default streams take well over half the downlink (not
    ok), params/serial_115200.toml brings them under half (ok). One SITL, two connections."""
    from companion.autopilot.preflight.report import Status, requirements_from_config
    from companion.autopilot.preflight.runner import preflight
    from companion.config import load_config

    relay = SerialRelay(baud=115200, seed=57)
    rows = {}
    with relay, _arducopter_on_serial(ardupilot_root, tmp_path, relay):
        for name, overlays in (("defaults", ()), ("serial_115200", ("serial_115200.toml",))):
            files = [shipped_params_path(f) for f in ("sitl_short.toml", *overlays)]
            config = load_config(
                *files,
                overrides={"autopilot": "ardupilot", "connection": f"serial://{relay.companion_device}:115200"},
            )
            ap = ArduPilotAutopilot.from_config(config)
            try:
                await ap.connect(timeout_s=30.0)
                await asyncio.sleep(2.0)  # the streams at the rates just asked for
                before = relay.to_companion.snapshot()
                t0 = time.monotonic()
                report = await preflight(ap, requirements_from_config(config), stream_window_s=3.0)
                relay_down = (relay.to_companion.snapshot().line - before.line) / (time.monotonic() - t0)
            finally:
                await ap.close()
            (row,) = [c for c in report.checks if c.name == "link budget"]
            rows[name] = row
            print(f"\n{name}: {row.status.value} {row.value}: {row.detail}; relay counted {relay_down:.0f} B/s down")
            measured = float(row.detail.split("down ", 1)[1].split(" B/s", 1)[0])
            assert abs(measured - relay_down) < 0.15 * relay_down, (measured, relay_down)
    assert rows["defaults"].status in (Status.WARN, Status.WRONG), rows["defaults"]
    assert rows["serial_115200"].status is Status.OK, rows["serial_115200"]
