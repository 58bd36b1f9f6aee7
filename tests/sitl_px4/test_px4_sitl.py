"""Against a real PX4 SITL build (SIH quad): skipped with the reason when no build is found."""

from __future__ import annotations

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion_sitl.px4_sitl import Px4NotFound, Px4Sitl, find_px4

pytestmark = pytest.mark.sitl


@pytest.fixture(scope="module")
def px4_root():
    try:
        return find_px4()
    except Px4NotFound as err:
        pytest.skip(str(err))


def test_find_px4_reports_where_it_looked(tmp_path):
    with pytest.raises(Px4NotFound, match="no PX4 SITL build at"):
        find_px4(tmp_path)


async def test_px4_sitl_connects_and_arms(px4_root, tmp_path):
    with Px4Sitl(px4_root, log_path=tmp_path / "px4.log"):
        ap = Px4Autopilot("udpin://127.0.0.1:14540")
        await ap.connect(timeout_s=15.0)
        try:
            assert ap.link_ok
        finally:
            await ap.close()


async def test_delivery_on_px4_sih_lands_on_the_displaced_pad(px4_root, tmp_path):
    """The sitl_short delivery against PX4 SIH: MAVSDK on the offboard link (14540), ground truth
    from HIL_STATE_QUATERNION on the GCS link (14550), camera and UWB rendered from it around a
    pad displaced 0.75 m from its configured position."""
    import asyncio

    from companion.config import load_config, shipped_params_path
    from companion_sitl.truth_feed import MavlinkTruth
    from companion_sitl.truth_harness import fly_on_truth

    config = load_config(shipped_params_path("sitl_short.toml"))
    with Px4Sitl(px4_root, log_path=tmp_path / "px4.log"), MavlinkTruth("udpin:127.0.0.1:14550") as truth:
        await asyncio.to_thread(truth.wait, 30.0)
        ap = Px4Autopilot("udpin://127.0.0.1:14540", link_timeout_s=config.runtime.link_timeout_s)
        try:
            r = await fly_on_truth(config, ap, truth, truth.origin, (0.6, -0.45), timeout_s=240.0)
        finally:
            await ap.close()
    assert r.delivered and r.returned, r.failure
    assert r.markers_used > 20
    assert r.pad_landing_error_m < 0.3, r
