import math

import numpy as np
import pytest

from companion.geometry import GeoPoint, MissionFrame, geo_to_ned, ned_to_geo


def test_one_degree_of_latitude_and_longitude():
    # Known WGS-84 arc lengths: 1 deg latitude at 45 deg ~ 111 132 m; 1 deg longitude at the
    # equator ~ 111 320 m (small-angle flat-earth uses the local radii of curvature).
    n, e, _ = geo_to_ned(GeoPoint(44.995, 10.0, 0.0), GeoPoint(45.005, 10.0, 0.0))
    assert abs(n / 0.01 - 111_132) < 20 and abs(e) < 1e-6
    n, e, _ = geo_to_ned(GeoPoint(0.0, 10.0, 0.0), GeoPoint(0.0, 10.001, 0.0))
    assert abs(e / 0.001 - 111_320) < 5


def test_flat_earth_round_trip_and_down():
    o = GeoPoint(-19.869, -43.9638, 850.0)
    g = ned_to_geo(o, 70.73, 70.73, -12.0)
    assert math.isclose(g.alt_amsl_m, 862.0)
    n, e, d = geo_to_ned(o, g)
    assert np.allclose((n, e, d), (70.73, 70.73, -12.0), atol=1e-6)
    assert math.isclose(math.hypot(n, e), 100.03, abs_tol=0.01)


def test_geo_point_rejects_bad_values():
    with pytest.raises(ValueError, match="lat_deg"):
        GeoPoint(91.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="finite"):
        GeoPoint(float("nan"), 0.0, 0.0)


def test_mission_frame_axes():
    # start at origin, pad 100 m east: F_I x = east, z = up, y = north (left of travel)
    f = MissionFrame.from_start_and_pad([0, 0, 0], [0, 100, 0])
    assert np.allclose(f.point_from_ned([0, 0, 0]), [-100, 0, 0])
    assert np.allclose(f.point_from_ned([0, 100, -10]), [0, 0, 10])
    assert np.allclose(f.vector_from_ned([1, 0, 0]), [0, 1, 0], atol=1e-12)
    assert math.isclose(np.linalg.det(f.R_ned_mission), 1.0)
    assert math.isclose(f.yaw_to_ned(0.0), math.pi / 2)


@pytest.mark.parametrize("heading", [0.0, 0.7, 2.5, -2.0])
def test_mission_frame_round_trip(heading):
    pad = np.array([10.0, -20.0, 1.5])
    f = MissionFrame(pad, heading)
    p = np.array([3.0, -4.0, -7.0])
    assert np.allclose(f.point_to_ned(f.point_from_ned(p)), p)
    assert np.allclose(f.vector_from_ned(f.vector_to_ned(p)), p)


def test_mission_frame_undefined_when_start_on_pad():
    with pytest.raises(ValueError, match="coincide"):
        MissionFrame.from_start_and_pad([1, 1, 0], [1, 1, -5])
