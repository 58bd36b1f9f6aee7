"""The sitl_short delivery against a real ArduCopter SITL with the companion capped to one Raspberry
Pi 4 core's share of this machine's core (docs/cpu-budget.md), with the slow board's settings
(params/slow_board.toml) and the kernel's 100 ms CFS period, as `companion bench app` measures it.
The SITL is started first and stays outside the cap; in this process the companion's threads run
inside it, and the threads that stand in for the world (the truth reader, the camera's rendering)
are kept out, as the MAVLink sim vehicle's are in the bench. The figures (overruns, the largest
setpoint gap in GUIDED against GUID_TIMEOUT, the landing on truth) are printed; the test asserts the
mission's goal, which an offboard failsafe would have ended, and the landing on the pad."""

from __future__ import annotations

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.bench.app import capped_flight_report
from companion_lab.cpu_cap import cap_unavailable, capped_process, pi4_factor_here

from .conftest import GRIPPER_SERVO9, arducopter
from .test_arducopter_delivery import PAD_OFFSET, _config

pytestmark = pytest.mark.firmware

PERIOD_US = 100_000  # the kernel's default CFS period (docs/cpu-budget.md: both periods' figures)


async def test_delivery_on_arducopter_with_the_companion_at_the_pi4_cpu_cap(ardupilot_root, tmp_path):
    why = cap_unavailable()
    if why:
        pytest.skip(f"no CPU cap here: {why}")
    pi4 = pi4_factor_here()  # this host's, measured: the built-in factor is one machine's
    with arducopter(ardupilot_root, tmp_path, extra_params=GRIPPER_SERVO9) as (sitl, truth):
        config = _config(sitl.connection, overlays=("slow_board.toml",))
        ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
        rec = FlightRecorder(tmp_path / "run", config)
        try:
            with capped_process(pi4, period_us=PERIOD_US, world_outside=True) as cg:
                r = await fly_on_truth(config, ap, truth, truth.origin, PAD_OFFSET, timeout_s=400.0, recorder=rec)
                throttled = cg.throttled()
        finally:
            rec.close()
            await ap.close()
    if not (r.delivered and r.returned):
        print(flight_story(tmp_path / "run", tmp_path / "arducopter.log"))
    print("\n" + capped_flight_report("ardupilot", pi4, r, tmp_path / "run", throttled))
    assert r.delivered and r.returned, r.failure
    assert r.pad_landing_error_m < 0.5, r  # on the pad
