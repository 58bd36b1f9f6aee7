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
