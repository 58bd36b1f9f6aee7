"""FCF-CF's in-place history shift (only the entries at or after a delayed frame's exposure)
against the straightforward rebuild of the whole history, on seeded frames with delays."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import pytest

from companion.dart.estimators import CameraMarkerObservation, FcfCfEstimator
from companion.geometry import wrap_angle
from companion_lab.bench.dart import _synthetic


class _RebuildingFcfCf(FcfCfEstimator):
    """The history shift as first written: every entry visited, a new deque built."""

    def _shift_history(self, t: float, jump: tuple[float, ...]) -> None:
        j0, j1, j2 = jump
        self._history = deque(
            (e[0], wrap_angle(e[1] + j0), wrap_angle(e[2] + j1), wrap_angle(e[3] + j2)) if e[0] >= t else e
            for e in self._history
        )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_in_place_shift_equals_rebuilding_the_history(seed):
    imu, obs = _synthetic(1500, seed=seed)
    rng = np.random.default_rng(seed)
    fast, ref = FcfCfEstimator(), _RebuildingFcfCf()
    shifted = 0
    for k, (t, g, a) in enumerate(imu):
        assert fast.update_imu(t, g, a) == ref.update_imu(t, g, a)
        if k % 4:
            continue
        o = obs[k]
        # exposure 0-120 ms before now, and a rotation error so the corrections jump
        if k % 8:
            exposure = max(0.0, t - float(rng.uniform(0.0, 0.12)))
        else:  # exactly at an IMU sample's time (the entry at t itself is shifted too)
            exposure = imu[max(0, k - int(rng.integers(0, 24)))][0]
        R = o.R_cam_marker @ _small_rotation(rng)
        frame = CameraMarkerObservation(exposure, R, o.t_cam_marker_m)
        before = list(ref.attitude_history)
        e1, e2 = fast.update_vision(frame), ref.update_vision(frame)
        assert e1 == e2
        assert list(fast.attitude_history) == list(ref.attitude_history)
        shifted += sum(1 for x, y in zip(before, ref.attitude_history, strict=True) if x != y)
    assert fast.accepted_observations > 300 and shifted > 1000  # the tails were really shifted


def _small_rotation(rng: np.random.Generator) -> np.ndarray:
    a = rng.normal(0.0, 0.02, 3)
    cx, sx, cy, sy, cz, sz = (f(v) for v in a for f in (math.cos, math.sin))
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx
