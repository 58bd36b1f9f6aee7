"""The wind go / no-go on the real ArduCopter SITL: SIM_WIND_SPD blows, EKF3 estimates the wind from
the drag (EK3_DRAG_BCOEF_X/Y, EK3_DRAG_MCOEF: without them ArduCopter estimates none and sends no
WIND) and sends it as WIND; the companion asks for that stream and, once the estimate stays above
go_no_go.wind_limit_m_s in flight, abandons the delivery with the parcel and flies home. On the
ground the estimate is 0 (EKF3 learns the wind only from flight): the take-off check passes."""

from __future__ import annotations

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.config import shipped_params_path
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.params import load_simulated_config

from .conftest import GRIPPER_SERVO9, arducopter

pytestmark = pytest.mark.firmware

# The pad 80 m out at 15 m: ~30 s in the wind before the pad.
MISSION = {"height_m": 15.0, "pad": {"north_m": 56.6, "east_m": 56.6}}
# EK3_DRAG_* are not this SITL frame's: the estimate reads ~1/3 of SIM_WIND_SPD (3.2 m/s from the
# west in 10 m/s, measured after a flight), so the limit is 2 m/s.
WINDY = {
    "SIM_WIND_SPD": 10.0,
    "SIM_WIND_DIR": 270.0,
    "EK3_DRAG_BCOEF_X": 17.7,
    "EK3_DRAG_BCOEF_Y": 17.7,
    "EK3_DRAG_MCOEF": 0.18,
}


async def test_wind_above_the_limit_in_flight_brings_the_parcel_home(ardupilot_root, tmp_path):
    with arducopter(ardupilot_root, tmp_path, extra_params={**GRIPPER_SERVO9, **WINDY}) as (sitl, truth):
        tuning = firmware_tuning("ardupilot")
        config = load_simulated_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                "autopilot": "ardupilot",
                "connection": sitl.connection,
                "mission": {**tuning["mission"], **MISSION, "ready_timeout_s": 120.0},
                "landing": tuning["landing"],
                "go_no_go": {"wind_limit_m_s": 2.0, "wind_exceed_s": 2.0},
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
    print(f"\nfailure: {r.failure}; last wind estimate {ap.telemetry.wind}")
    assert r.returned and not r.delivered, r.failure
    assert (
        r.failure.startswith("returned without delivering: wind ") and "above go_no_go.wind_limit_m_s = 2" in r.failure
    )
