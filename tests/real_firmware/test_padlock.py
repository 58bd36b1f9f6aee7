"""No release off the pad on the real firmware (PX4 SIH, ArduCopter SITL; docs/delivery-policy.md):
the sitl_short delivery with camera and UWB fitted but dead all flight, on ArduCopter the gripper
enabled on servo 9. The policy holds at the approach height, flies the search, tries again and
flies home with the parcel: the autopilot is never asked to release (no release is ever asked of
ArduCopter's gripper)."""

from __future__ import annotations

import pytest

from companion.config import shipped_params_path
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.params import load_simulated_config

from .vehicles import AUTOPILOT_OVERRIDES, DELIVERY_BOOT_PARAMS, READY_MISSION, autopilot, sitl_with_truth

pytestmark = pytest.mark.firmware

# a short policy, so the flight stays within a few minutes: 2 s hold, a 3 m search at 4 m
POLICY = {
    "require_pad_lock": True,
    "hold_s": 2.0,
    "search_height_m": 4.0,
    "search_radius_m": 3.0,
    "search_spacing_m": 2.5,
    "search_dwell_s": 0.5,
    "descent_tries": 2,
}
TIMEOUT_S = {"px4": 300.0, "ardupilot": 360.0}


async def test_with_camera_and_uwb_dead_flies_home_with_the_parcel(firmware, tmp_path):
    name, root = firmware
    tuning = firmware_tuning(name)
    with sitl_with_truth(name, root, tmp_path, extra_params=DELIVERY_BOOT_PARAMS[name]) as (connection, truth, log):
        config = load_simulated_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                **AUTOPILOT_OVERRIDES[name],
                "connection": connection,
                "mission": {**tuning["mission"], **READY_MISSION[name], "return_home": True},
                "landing": {**tuning["landing"], "fusion": True, "policy": POLICY},
                "sim": {"camera_fails_below_m": 10000.0, "uwb_fails_below_m": 10000.0},
            },
        )
        ap = autopilot(name, config)
        rec = FlightRecorder(tmp_path / "run", config)
        try:
            r = await fly_on_truth(config, ap, truth, truth.origin, (0.0, 0.0), timeout_s=TIMEOUT_S[name], recorder=rec)
        finally:
            rec.close()
            await ap.close()
    print("\n".join(r.pad_lock_events))
    if not r.returned:
        print(flight_story(tmp_path / "run", log))
    assert r.markers_used == 0 and r.uwb_used == 0
    assert not r.delivered and r.releases == 0, r
    assert r.returned and r.home_with_parcel, r.failure
    assert r.pad_tries == 2 and r.failure.startswith("parcel not delivered"), r.failure
    assert any("searching within 3.0 m" in e for e in r.pad_lock_events), r.pad_lock_events
    assert r.touchdown_truth_ne_m[0] != r.touchdown_truth_ne_m[0]  # nan: never landed on the way out
