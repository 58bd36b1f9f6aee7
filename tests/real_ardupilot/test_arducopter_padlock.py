"""No release off the pad on real ArduCopter SITL (docs/delivery-policy.md): the sitl_short
delivery with camera and UWB fitted but dead all flight, the gripper enabled on servo 9. The
policy holds, searches, tries again and flies home with the parcel: no release is ever asked of
the gripper."""

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

POLICY = {
    "require_pad_lock": True,
    "hold_s": 2.0,
    "search_height_m": 4.0,
    "search_radius_m": 3.0,
    "search_spacing_m": 2.5,
    "search_dwell_s": 0.5,
    "descent_tries": 2,
}


async def test_arducopter_with_camera_and_uwb_dead_flies_home_with_the_parcel(ardupilot_root, tmp_path):
    tuning = firmware_tuning("ardupilot")
    with arducopter(ardupilot_root, tmp_path, extra_params=GRIPPER_SERVO9) as (sitl, truth):
        config = load_simulated_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                "autopilot": "ardupilot",
                "connection": sitl.connection,
                "mission": {**tuning["mission"], "ready_timeout_s": 120.0, "return_home": True},
                "landing": {**tuning["landing"], "fusion": True, "policy": POLICY},
                "sim": {"camera_fails_below_m": 10000.0, "uwb_fails_below_m": 10000.0},
            },
        )
        ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
        rec = FlightRecorder(tmp_path / "run", config)
        try:
            r = await fly_on_truth(config, ap, truth, truth.origin, (0.0, 0.0), timeout_s=360.0, recorder=rec)
        finally:
            rec.close()
            await ap.close()
    print("\n".join(r.pad_lock_events))
    if not r.returned:
        print(flight_story(tmp_path / "run", tmp_path / "arducopter.log"))
    assert r.markers_used == 0 and r.uwb_used == 0
    assert not r.delivered and r.releases == 0, r
    assert r.returned and r.home_with_parcel, r.failure
    assert r.pad_tries == 2 and r.failure.startswith("parcel not delivered"), r.failure
    assert any("searching within 3.0 m" in e for e in r.pad_lock_events), r.pad_lock_events
