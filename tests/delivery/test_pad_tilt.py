"""The autopilot's roll / pitch error measured on a level pad (companion.delivery.pad_tilt)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from companion.delivery.attitude_history import AttitudeHistory
from companion.delivery.pad_tilt import MIN_OBSERVATIONS, TILT_WINDOW_S, PadTiltEstimator
from companion.geometry.mounts import downward_mount, pad_pose_ned
from companion.geometry.rotations import euler_to_rotmat, rotmat_to_euler

R_BC = downward_mount().R
R_WP = pad_pose_ned(yaw_rad=math.radians(-40.0)).R


def seen(true_att_deg: tuple[float, float, float]) -> np.ndarray:
    """R_camera_pad of the level pad from a vehicle truly at ``true_att_deg``."""
    return (euler_to_rotmat(*np.radians(true_att_deg)) @ R_BC).T @ R_WP


def reported(true_att_deg: tuple[float, float, float], err_deg: tuple[float, float]) -> tuple[float, float, float]:
    E = Rotation.from_rotvec([math.radians(err_deg[0]), math.radians(err_deg[1]), 0.0]).as_matrix()
    return rotmat_to_euler(E @ euler_to_rotmat(*np.radians(true_att_deg)))


def test_the_tilt_is_taken_out_once_enough_observations_count() -> None:
    hist = AttitudeHistory()
    est = PadTiltEstimator(hist)
    true = (1.0, -3.0, 75.0)
    rep = reported(true, (2.0, -1.5))
    for k in range(MIN_OBSERVATIONS):
        t = 0.05 * k
        hist.add(t, *rep)
        assert est.corrected(rep) == pytest.approx(rep)  # not yet: as reported
        assert est.on_observation(t, seen(true), R_BC)
    assert np.degrees(est.tilt_rotvec[:2]) == pytest.approx([2.0, -1.5], abs=1e-6)  # type: ignore[index]
    assert euler_to_rotmat(*est.corrected(rep)) == pytest.approx(euler_to_rotmat(*np.radians(true)), abs=1e-6)


def test_only_the_recent_window_counts_and_a_tilt_beyond_the_bound_is_rejected() -> None:
    hist = AttitudeHistory(keep_s=100.0)
    est = PadTiltEstimator(hist, max_tilt_rad=math.radians(6.0))
    true = (0.0, 0.0, 10.0)
    for k in range(81):  # 8 s at 10 Hz: the error about north grows 0.5 deg/s
        t = 0.1 * k
        rep = reported(true, (0.5 * t, 0.0))
        hist.add(t, *rep)
        assert est.on_observation(t, seen(true), R_BC)
    # the mean of the last TILT_WINDOW_S (2 s: 21 observations, 3.0 ... 4.0 deg): 3.5 deg
    assert math.degrees(est.tilt_rotvec[0]) == pytest.approx(4.0 - 0.5 * TILT_WINDOW_S / 2, abs=1e-6)  # type: ignore[index]
    hist.add(8.1, *reported(true, (8.0, 0.0)))
    assert not est.on_observation(8.1, seen(true), R_BC)  # 8 deg: a wrong pose or a sloping pad
    assert est.rejected == 1


def test_bad_setup_is_refused() -> None:
    with pytest.raises(ValueError, match="max_tilt_rad"):
        PadTiltEstimator(AttitudeHistory(), max_tilt_rad=math.nan)
    with pytest.raises(ValueError, match="min_observations"):
        PadTiltEstimator(AttitudeHistory(), min_observations=0)
