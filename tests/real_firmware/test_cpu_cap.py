"""The sitl_short delivery against the real firmware (PX4 SIH, ArduCopter SITL) with the companion
capped to one Raspberry Pi 4 core's share of this machine's core (docs/cpu-budget.md), with the
slow board's settings (params/slow_board.toml) and the kernel's 100 ms CFS period, as `companion
bench app` measures it. The SITL is started first and stays outside the cap; in this process the
companion's threads (on PX4 MAVSDK's core among them) run inside it, and the threads that stand in
for the world (the truth reader, the camera's rendering) are kept out, as the MAVLink sim
vehicle's are in the bench. The figures (overruns, the largest setpoint gap in offboard against
PX4's COM_OF_LOSS_T or in GUIDED against ArduCopter's GUID_TIMEOUT, the landing on truth) are
printed; the test asserts the mission's goal, which an offboard failsafe would have ended, and the
landing on the pad (the landing against the uncapped one is a figure of several flights:
docs/performance.md, "A Pi-sized CPU budget")."""

from __future__ import annotations

import math

import pytest

from companion.config import shipped_params_path
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.bench.app import capped_flight_report
from companion_lab.cpu_cap import cap_unavailable, capped_process, pi4_factor_here
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.params import load_simulated_config

from .vehicles import GRIPPER_SERVO9, autopilot, sitl_with_truth

pytestmark = pytest.mark.firmware

PERIOD_US = 100_000  # the kernel's default CFS period (docs/cpu-budget.md: both periods' figures)
# the pad 1.5 m from where the parameters say: GPS alone would land 1.5 m off the true pad (SIH
# cannot bias GPS); the directions those of tests/real_px4/test_px4_sitl.py and
# tests/real_ardupilot/test_arducopter_delivery.py
PAD_OFFSET_M = {"px4": (1.5 / math.sqrt(2.0), 1.5 / math.sqrt(2.0)), "ardupilot": (1.2, -0.9)}
EXTRA_PARAMS = {"px4": {}, "ardupilot": GRIPPER_SERVO9}
# ArduCopter: the companion told it flies ArduPilot; EKF3 uses GPS ~41 s after boot (the ready
# timeout)
OVERRIDES = {"px4": {}, "ardupilot": {"autopilot": "ardupilot"}}
MISSION = {"px4": {}, "ardupilot": {"ready_timeout_s": 120.0, "return_home": True}}


async def test_delivery_with_the_companion_at_one_pi4_core(firmware, tmp_path):
    name, root = firmware
    why = cap_unavailable()
    if why:
        pytest.skip(f"no CPU cap here: {why}")
    pi4 = pi4_factor_here()  # this host's, measured: the built-in factor is one machine's
    tuning = firmware_tuning(name)  # on ArduCopter params/ardupilot_quad.toml: landing and GUIDED's accel limits
    with sitl_with_truth(name, root, tmp_path, extra_params=EXTRA_PARAMS[name]) as (connection, truth, log):
        config = load_simulated_config(
            shipped_params_path("sitl_short.toml"),
            shipped_params_path("slow_board.toml"),
            overrides={
                **OVERRIDES[name],
                "connection": connection,
                "mission": {**tuning["mission"], **MISSION[name]},
                "landing": tuning["landing"],
            },
        )
        # the whole process joins the cap (and what it starts from then on), the flight inside
        # it; the autopilot is made and closed inside it too
        with capped_process(pi4, period_us=PERIOD_US, world_outside=True) as cg:
            ap = autopilot(name, config)
            rec = FlightRecorder(tmp_path / "run", config)
            try:
                r = await fly_on_truth(
                    config, ap, truth, truth.origin, PAD_OFFSET_M[name], timeout_s=400.0, recorder=rec
                )
                throttled = cg.throttled()
            finally:
                rec.close()
                await ap.close()
    if not (r.delivered and r.returned):
        print(flight_story(tmp_path / "run", log))
    print("\n" + capped_flight_report(name, pi4, r, tmp_path / "run", throttled))
    assert r.delivered and r.returned, r.failure
    assert r.pad_landing_error_m < 0.5, r  # on the pad
