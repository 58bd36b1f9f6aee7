"""DeliveryPath's in-plane distance (the path scoring and the truth harness use it)."""

from __future__ import annotations

import pytest

from companion.guidance.path import DeliveryPath


def test_distance_in_plane_leaves_the_lateral_offset_out():
    path = DeliveryPath(h=8.0, r=2.0, d=20.0)
    on_cruise_beside = (-10.0, 1.5, 8.0)  # on the cruise (S3, z = h), 1.5 m to the side
    assert path.distance_to_path(on_cruise_beside) == pytest.approx(1.5)
    assert path.distance_in_plane(on_cruise_beside) == pytest.approx(0.0, abs=1e-12)
    above_and_beside = (-10.0, -2.0, 8.5)  # 0.5 m above the cruise as well
    assert path.distance_in_plane(above_and_beside) == pytest.approx(0.5)
