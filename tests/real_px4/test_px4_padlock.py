"""No release off the pad on real PX4 SIH (docs/delivery-policy.md): the sitl_short delivery with
camera and UWB fitted but dead all flight. The policy holds at the approach height, flies the
search, tries again and flies home with the parcel: PX4 is never asked to release."""

from __future__ import annotations

import asyncio

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.config import shipped_params_path
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.px4_sitl import Px4Sitl
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.params import load_simulated_config

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


async def test_px4_with_camera_and_uwb_dead_flies_home_with_the_parcel(px4_root, tmp_path):
    tuning = firmware_tuning("px4")
    config = load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "mission": {**tuning["mission"], "return_home": True},
            "landing": {**tuning["landing"], "fusion": True, "policy": POLICY},
            "sim": {"camera_fails_below_m": 10000.0, "uwb_fails_below_m": 10000.0},
        },
    )
    with Px4Sitl(px4_root, log_path=tmp_path / "px4.log"), MavlinkTruth("udpin:127.0.0.1:14550") as truth:
        await asyncio.to_thread(truth.wait, 30.0)
        ap = Px4Autopilot.from_config(config.model_copy(update={"connection": "udpin://127.0.0.1:14540"}))
        rec = FlightRecorder(tmp_path / "run", config)
        try:
            r = await fly_on_truth(config, ap, truth, truth.origin, (0.0, 0.0), timeout_s=300.0, recorder=rec)
        finally:
            rec.close()
            await ap.close()
    print("\n".join(r.pad_lock_events))
    if not r.returned:
        print(flight_story(tmp_path / "run", tmp_path / "px4.log"))
    assert r.markers_used == 0 and r.uwb_used == 0
    assert not r.delivered and r.releases == 0, r
    assert r.returned and r.home_with_parcel, r.failure
    assert r.pad_tries == 2 and r.failure.startswith("parcel not delivered"), r.failure
    assert any("searching within 3.0 m" in e for e in r.pad_lock_events), r.pad_lock_events
    assert r.touchdown_truth_ne_m[0] != r.touchdown_truth_ne_m[0]  # nan: never landed on the way out
