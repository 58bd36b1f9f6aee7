"""The drop-zone check on the real firmware (PX4 SIH, ArduCopter SITL; docs/drop-zone.md): the
sitl_short delivery with a box on the pad in the truth-rendered camera's frames. The descent does
not start, the vehicle holds 2 s, and the parcel flies home: nothing is released."""

from __future__ import annotations

import pytest

from companion.config import shipped_params_path
from companion_firmware.truth_harness import flight_story, fly_on_truth
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.params import load_simulated_config

from .vehicles import AUTOPILOT_OVERRIDES, DELIVERY_BOOT_PARAMS, READY_MISSION, autopilot, sitl_with_truth

pytestmark = pytest.mark.firmware

TIMEOUT_S = {"px4": 240.0, "ardupilot": 300.0}


async def test_a_box_on_the_pad_holds_and_the_parcel_flies_home(firmware, tmp_path):
    name, root = firmware
    tuning = firmware_tuning(name)
    with sitl_with_truth(name, root, tmp_path, extra_params=DELIVERY_BOOT_PARAMS[name]) as (connection, truth, log):
        config = load_simulated_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                **AUTOPILOT_OVERRIDES[name],
                "connection": connection,
                "mission": {**tuning["mission"], **READY_MISSION[name], "return_home": True},
                "landing": {**tuning["landing"], "fusion": True, "drop_zone": {"enabled": True, "hold_s": 2.0}},
                "sim": {"camera": {"occluder": {"kind": "box"}}},
            },
        )
        ap = autopilot(name, config)
        try:
            r = await fly_on_truth(config, ap, truth, truth.origin, (0.0, 0.0), timeout_s=TIMEOUT_S[name])
        finally:
            await ap.close()
    print("\n".join(r.drop_zone_events + r.pad_lock_events), "\nfusion:", r.fusion_outcomes)
    if not r.returned:
        print(flight_story(tmp_path / "run", log))
    assert r.drop_zone_events and r.drop_zone_events[0].startswith("an object on the pad"), r.drop_zone_events
    assert any(e.startswith("drop zone not clear after holding 2 s") for e in r.drop_zone_events)
    assert not r.delivered and r.releases == 0, r
    assert r.returned and r.home_with_parcel, r.failure
