"""The sitl_short delivery against the real PX4 SIH with the companion capped to one Raspberry Pi 4
core's share of this machine's core (docs/cpu-budget.md), with the slow board's settings
(params/slow_board.toml) and the kernel's 100 ms CFS period, as `companion bench app` measures it.
PX4 is started first and stays outside the cap; in this process the companion's threads (MAVSDK's
core among them) run inside it, and the threads that stand in for the world (the truth reader, the
camera's rendering) are kept out. The figures (overruns, the largest setpoint gap in offboard
against COM_OF_LOSS_T, the landing on truth) are printed; the test asserts the mission's goal,
which an offboard failsafe would have ended, and the landing on the pad (the landing against the
uncapped one is a figure of several flights: docs/performance.md, "A Pi-sized CPU budget")."""

from __future__ import annotations

import asyncio

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.config import shipped_params_path
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.px4_sitl import Px4Sitl
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.bench.app import capped_flight_report
from companion_lab.cpu_cap import cap_unavailable, capped_process, pi4_factor_here
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.params import load_simulated_config

from .test_px4_sitl import PAD_OFFSET_M

pytestmark = pytest.mark.firmware

PERIOD_US = 100_000  # the kernel's default CFS period (docs/cpu-budget.md: both periods' figures)


async def test_delivery_on_px4_with_the_companion_at_one_pi4_core(px4_root, tmp_path):
    why = cap_unavailable()
    if why:
        pytest.skip(f"no CPU cap here: {why}")
    pi4 = pi4_factor_here()  # this host's, measured: the built-in factor is one machine's
    tuning = firmware_tuning("px4")
    config = load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        shipped_params_path("slow_board.toml"),
        overrides={"mission": tuning["mission"], "landing": tuning["landing"]},
    )
    with Px4Sitl(px4_root, log_path=tmp_path / "px4.log"), MavlinkTruth("udpin:127.0.0.1:14550") as truth:
        await asyncio.to_thread(truth.wait, 30.0)
        with capped_process(pi4, period_us=PERIOD_US, world_outside=True) as cg:
            ap = Px4Autopilot.from_config(config.model_copy(update={"connection": "udpin://127.0.0.1:14540"}))
            rec = FlightRecorder(tmp_path / "run", config)
            try:
                r = await fly_on_truth(config, ap, truth, truth.origin, PAD_OFFSET_M, timeout_s=400.0, recorder=rec)
                throttled = cg.throttled()
            finally:
                rec.close()
                await ap.close()
    if not (r.delivered and r.returned):
        print(flight_story(tmp_path / "run", tmp_path / "px4.log"))
    print("\n" + capped_flight_report("px4", pi4, r, tmp_path / "run", throttled))
    assert r.delivered and r.returned, r.failure
    assert r.pad_landing_error_m < 0.5, r  # on the pad
