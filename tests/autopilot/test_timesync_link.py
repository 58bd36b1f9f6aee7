"""TIMESYNC over the ArduPilot backend against the MAVLink sim vehicle (real time, loopback): the
vehicle answers as the firmware does, the backend estimates its boot clock's offset."""

from __future__ import annotations

import asyncio
import math
import time

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot


async def test_ardupilot_backend_estimates_the_sim_vehicles_boot_clock(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port) as sim:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}", timesync_period_s=0.05)
        assert ap.clock_offset is None
        await ap.connect(timeout_s=3.0)
        await mav.wait_for(lambda: ap.clock_offset is not None and ap.clock_offset.samples >= 8, 5.0, "offset")
        off = ap.clock_offset
        assert off is not None
        truth_s = sim.now - time.monotonic()  # the vehicle's boot clock minus ours
        assert abs(off.offset_s - truth_s) < 0.005
        assert 0.0 < off.rtt_min_s <= off.rtt_median_s < 0.1
        assert off.jumps == 0 and off.jitter_s < 0.005
        assert abs(off.to_companion_s(sim.now) - time.monotonic()) < 0.005
        assert ap.timesync is not None and sum(ap.timesync.rejected.values()) == 0
        await ap.close()


async def test_timesync_off_by_default_sends_none(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port) as sim:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        await ap.connect(timeout_s=3.0)
        await asyncio.sleep(0.3)
        assert ap.clock_offset is None and ap.timesync is None
        assert sim.stats.by_type_in.get("TIMESYNC", 0) == 0
        await ap.close()


async def test_px4_backend_estimates_it_through_mavlink_direct(mav, udp_port):
    from companion.autopilot.px4 import Px4Autopilot

    config = mav.short_config()
    with mav.sim_vehicle(config, "px4", udp_port) as sim:
        ap = Px4Autopilot(f"udpin://127.0.0.1:{udp_port}", timesync_period_s=0.05)
        await ap.connect(timeout_s=10.0)
        try:
            await mav.wait_for(lambda: ap.clock_offset is not None and ap.clock_offset.samples >= 8, 8.0, "offset")
            off = ap.clock_offset
            assert off is not None
            truth_s = sim.now - time.monotonic()
            # MAVSDK's hop (mavsdk_server, gRPC) is in the RTT; the midpoint stays within RTT / 2
            assert abs(off.offset_s - truth_s) < max(0.005, off.rtt_min_s / 2 + 0.001)
            assert 0.0 < off.rtt_min_s < 0.1 and off.jumps == 0
        finally:
            await ap.close()


async def test_a_step_of_the_vehicles_clock_is_one_jump(mav, udp_port, caplog):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port) as sim:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}", timesync_period_s=0.05)
        await ap.connect(timeout_s=3.0)
        try:
            await mav.wait_for(lambda: ap.clock_offset is not None and ap.clock_offset.samples >= 8, 5.0, "offset")
            before = ap.clock_offset
            assert before is not None
            with caplog.at_level("WARNING", logger="companion.autopilot.timesync"):
                with sim.lock:
                    sim._t0 -= 30.0  # the vehicle's boot clock steps 30 s ahead (its physics follow)
                await mav.wait_for(lambda: (o := ap.clock_offset) is not None and o.jumps == 1, 5.0, "the jump")
            after = ap.clock_offset
            assert after is not None and after.jumps == 1
            assert after.offset_s - before.offset_s == pytest.approx(30.0, abs=0.01)
            assert "autopilot clock jump" in caplog.text
        finally:
            await ap.close()


async def test_samples_stamped_at_their_time_boot_ms_on_our_clock(mav, udp_port):
    from companion.autopilot.types import Attitude, PositionNed

    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port):
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}", timesync_period_s=0.05, sample_time="autopilot")
        got: list[tuple[float, float]] = []
        ap.telemetry.add_listener(
            lambda s: got.append((time.monotonic(), s.time_s)) if isinstance(s, (Attitude, PositionNed)) else None
        )
        await ap.connect(timeout_s=3.0)
        try:
            await mav.wait_for(lambda: ap.clock_offset is not None and ap.clock_offset.samples >= 8, 5.0, "offset")
            ap._next_timesync_s = math.inf  # no more exchanges: the offset holds still from here
            await asyncio.sleep(0.2)
            off = ap._sample_offset
            got.clear()
            await asyncio.sleep(0.5)
            assert off is not None and ap._sample_offset == off
            assert len(got) > 20 and ap.sample_times_refused == 0
            assert all(0.0 <= seen_s - t_s < 0.1 for seen_s, t_s in got)  # before we saw it, not long before
            # the autopilot's whole milliseconds: time_boot_ms mapped (a receipt time would be whole
            # to 1 us one time in 500); those not whole were later than their receipt, so stamped at it
            ms = [(t_s + off.offset_s) * 1e3 for _, t_s in got]
            whole = sum(abs(x - round(x)) < 1e-3 for x in ms)
            assert whole >= 0.5 * len(ms), (whole, len(ms))
        finally:
            await ap.close()


def test_sample_time_autopilot_needs_timesync_and_ardupilot(mav):
    from companion.autopilot import AutopilotError
    from companion.autopilot.px4 import Px4Autopilot

    with pytest.raises(AutopilotError, match="autopilot_timesync_hz > 0"):
        ArduPilotAutopilot("udpin:127.0.0.1:1", sample_time="autopilot")
    config = mav.short_config()
    rt = config.runtime.model_copy(update={"autopilot_sample_time": "autopilot", "autopilot_timesync_hz": 2.0})
    config = config.model_copy(update={"runtime": rt})
    ap = ArduPilotAutopilot.from_config(config.model_copy(update={"connection": "udpin:127.0.0.1:1"}))
    assert ap.sample_time == "autopilot" and ap.timesync_period_s == 0.5
    with pytest.raises(AutopilotError, match="MAVSDK's telemetry carries no"):
        Px4Autopilot.from_config(config)
