"""Against a real ArduCopter SITL build: it answers our TIMESYNC (GCS_MAVLINK::handle_timesync:
tc1 = its boot time in ns, ts1 echoed), and the offset the backend estimates is its boot clock:
steady while the SITL runs in real time, some 40 s of boot behind our clock's now."""

from __future__ import annotations

import asyncio
import time

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot

from .conftest import arducopter, wait_for

pytestmark = pytest.mark.firmware


async def test_arducopter_answers_timesync_with_its_boot_clock(ardupilot_root, tmp_path):
    with arducopter(ardupilot_root, tmp_path, truth=False) as (sitl, _):
        ap = ArduPilotAutopilot(sitl.connection, timesync_period_s=0.1)
        await ap.connect(timeout_s=10.0)
        try:
            await wait_for(lambda: (o := ap.clock_offset) is not None and o.samples >= 10, 10.0, "10 TIMESYNC answers")
            first = ap.clock_offset
            assert first is not None
            await asyncio.sleep(2.0)
            later = ap.clock_offset
            assert later is not None and later.jumps == 0
            assert 0.0 < later.rtt_min_s < 0.05  # loopback to a real-time SITL
            assert abs(later.offset_s - first.offset_s) < 0.01  # one clock, at our clock's rate
            assert ap.timesync is not None and sum(ap.timesync.rejected.values()) == 0
            # the boot clock (ArduCopterSitl boots past EKF3's GPS wait, ~41 s simulated, first)
            assert 30.0 < later.to_autopilot_s(time.monotonic()) < 600.0
        finally:
            await ap.close()
