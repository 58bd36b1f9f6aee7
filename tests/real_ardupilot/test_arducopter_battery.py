"""The battery go / no-go on the real ArduCopter SITL: a small simulated battery (BATT_CAPACITY,
the remaining % ArduCopter computes from the current drawn, sent in SYS_STATUS / BATTERY_STATUS)
drains in a few minutes of flight; the companion measures the use in flight, abandons the delivery
with the parcel and flies home, landing before ArduCopter's remaining % reaches the reserve."""

from __future__ import annotations

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.config import load_config, shipped_params_path
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.real_campaign import firmware_tuning

from .conftest import GRIPPER_SERVO9, arducopter

pytestmark = pytest.mark.firmware

SMALL_BATTERY = {"BATT_CAPACITY": 400.0, "SIM_BATT_CAP_AH": 0.4}  # mAh; the simulated pack's Ah


async def test_a_small_battery_brings_the_parcel_home(ardupilot_root, tmp_path):
    with arducopter(ardupilot_root, tmp_path, extra_params={**GRIPPER_SERVO9, **SMALL_BATTERY}) as (sitl, truth):
        tuning = firmware_tuning("ardupilot")
        config = load_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                "autopilot": "ardupilot",
                "connection": sitl.connection,
                "mission": {**tuning["mission"], "ready_timeout_s": 120.0},
                "landing": tuning["landing"],
                "go_no_go": {"battery_check": True, "battery_reserve_pct": 30.0, "battery_measure_s": 15.0},
            },
        )
        assert truth is not None
        ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
        rec = FlightRecorder(tmp_path / "run", config)
        try:
            r = await fly_on_truth(config, ap, truth, truth.origin, (0.0, 0.0), timeout_s=400.0, recorder=rec)
        finally:
            rec.close()
            await ap.close()
    if not r.returned or r.delivered:
        print(flight_story(tmp_path / "run", tmp_path / "arducopter.log"))
    print(f"\nfailure: {r.failure}")
    assert r.returned and not r.delivered, r.failure
    # the go_no_go event's reason, kept as the mission's failure
    assert r.failure.startswith("returned without delivering: battery") and "(measured in flight)" in r.failure
