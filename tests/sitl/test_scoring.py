"""Path scoring on truth (companion_sitl.scoring): the whole distance to the reference path
(delivery eq 16-17: sqrt(alpha_1^2 + alpha_2^2)) and the distance within the path's vertical
plane (alpha_2 alone), against hand-computed points."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from companion.events import Phase
from companion.geometry.mission_frame import MissionFrame
from companion.guidance.path import DeliveryPath
from companion_sitl.scoring import PathScorer

H, R, D = 5.0, 2.0, 10.0


def _mission(true_pad_ne=None):
    start = np.array([0.0, 0.0, 0.0])
    pad = np.array([10.0, 0.0, 0.0])  # F_I: origin at the pad, x north, z up
    m = SimpleNamespace(frame=MissionFrame.from_start_and_pad(start, pad), path=DeliveryPath(H, R, D), start_ned=start)
    return m, PathScorer(true_pad_ne)


def test_cruise_point_lateral_and_vertical_offsets():
    m, sc = _mission()
    p = m.frame.point_to_ned([-5.0, 0.3, H + 0.4])  # the cruise (sector 3), 0.3 sideways, 0.4 high
    assert sc.distance(m, Phase.INBOUND, p) == pytest.approx(0.5, abs=1e-9)
    assert sc.in_plane_distance(m, Phase.INBOUND, p) == pytest.approx(0.4, abs=1e-9)


def test_arc_overshoot_is_the_radial_distance_without_the_sideways_part():
    m, sc = _mission()
    cx, cz = -R, H - R  # the second arc's centre (sector 4)
    th = math.radians(45.0)
    q = [cx + (R + 0.25) * math.cos(th), 1.0, cz + (R + 0.25) * math.sin(th)]  # 0.25 m outside, 1 m aside
    p = m.frame.point_to_ned(q)
    assert int(m.path.sector(q)) == 4
    assert sc.in_plane_distance(m, Phase.OUTBOUND, p) == pytest.approx(0.25, abs=1e-9)
    assert sc.distance(m, Phase.OUTBOUND, p) == pytest.approx(math.hypot(1.0, 0.25), abs=1e-9)


def test_on_the_way_out_the_path_to_the_true_pad_counts_too():
    # the true pad 1.5 m east of the configured one: a vehicle on its path is 1.5 m aside of the
    # configured path but on the reference
    m, sc = _mission(true_pad_ne=(10.0, 1.5))
    true_frame = MissionFrame.from_start_and_pad([0.0, 0.0, 0.0], [10.0, 1.5, 0.0])
    true_path = DeliveryPath(H, R, math.hypot(10.0, 1.5))
    p = true_frame.point_to_ned([-0.5 * true_path.d, 0.0, H])
    assert sc.distance(m, Phase.OUTBOUND, p) == pytest.approx(0.0, abs=1e-9)
    assert sc.in_plane_distance(m, Phase.OUTBOUND, p) == pytest.approx(0.0, abs=1e-9)
    assert sc.distance(m, Phase.INBOUND, p) > 0.7  # the way home has its own path only
