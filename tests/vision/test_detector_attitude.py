"""The attitude rule of resolve_ambiguity on hand-made IPPE mirror pairs, and its helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.geometry import euler_to_rotmat, rot_x, rot_y, rot_z
from companion.vision.detector import (
    DetectorConfig,
    PoseCandidate,
    down_in_camera,
    marker_normal_in_camera,
    resolve_ambiguity,
)

DOWN = rot_x(math.pi)  # T_camera_pad.R of a level camera straight above the pad (pad z to the camera)
CFG = DetectorConfig()  # attitude_agree 8 deg, margin 3 deg, err_ratio 0.6, prior margin 6 deg


def _cand(R: np.ndarray, err: float) -> PoseCandidate:
    return PoseCandidate(R, np.array([0.1, -0.2, 8.0]), err)


def _up_for(R_camera_pad: np.ndarray, tilt_error_deg: float = 0.0) -> np.ndarray:
    """The attitude's expected pad normal in the camera, the true one tilted by an error."""
    return rot_x(math.radians(tilt_error_deg)) @ R_camera_pad[:, 2]


def _pair(true_tilt_deg: float, mirror_tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Two poses whose pad normals lie true_tilt / mirror_tilt from the optical axis (a mirror pair
    on either side of the line of sight)."""
    return rot_y(math.radians(true_tilt_deg)) @ DOWN, rot_y(math.radians(mirror_tilt_deg)) @ DOWN


def test_attitude_picks_the_agreeing_solution_of_a_close_error_pair() -> None:
    truth, mirror = _pair(6.0, -9.0)
    for order in ((mirror, truth), (truth, mirror)):  # the mirror may fit the pixels as well or better
        c = [_cand(order[0], 0.30), _cand(order[1], 0.31)]
        up = _up_for(truth, tilt_error_deg=1.5)  # attitude 1.5 deg off
        # without the attitude (looking-down prior) this pair is undecided
        assert resolve_ambiguity(c, CFG, up_cam=np.array([0.0, 0.0, -1.0])).ambiguous
        r = resolve_ambiguity(c, CFG, up_cam=up, attitude=True)
        assert not r.ambiguous and r.resolved_by == "attitude"
        assert c[r.chosen].R is truth


def test_attitude_rejects_when_neither_solution_agrees() -> None:
    a, b = _pair(15.0, -15.0)
    up = np.array([0.0, 0.0, -1.0])  # the attitude says straight down: both normals 15 deg off
    r = resolve_ambiguity([_cand(a, 0.1), _cand(b, 0.5)], CFG, up_cam=up, attitude=True)
    assert (r.ambiguous, r.resolved_by) == (True, "attitude_disagrees")  # even with a decisive error ratio


def test_attitude_rejects_a_single_or_agreeing_pose_it_contradicts() -> None:
    off = rot_y(math.radians(15.0)) @ DOWN
    up = np.array([0.0, 0.0, -1.0])
    for c in ([_cand(off, 0.2)], [_cand(off, 0.2), _cand(rot_x(math.radians(0.5)) @ off, 0.2)]):
        r = resolve_ambiguity(c, CFG, up_cam=up, attitude=True)
        assert (r.ambiguous, r.resolved_by) == (True, "attitude_disagrees")
        # without the attitude the same pose passes (single / agree)
        assert not resolve_ambiguity(c, CFG, up_cam=up).ambiguous


def test_decisive_error_ratio_against_the_attitude_is_flagged() -> None:
    truth, mirror = _pair(4.0, -12.0)
    c = [_cand(mirror, 0.1), _cand(truth, 0.4)]  # noise made the mirror fit far better
    r = resolve_ambiguity(c, CFG, up_cam=_up_for(truth), attitude=True)
    assert (r.ambiguous, r.resolved_by) == (True, "conflict_attitude")
    # the error ratio and the attitude agreeing: accepted
    r = resolve_ambiguity([_cand(truth, 0.1), _cand(mirror, 0.4)], CFG, up_cam=_up_for(truth), attitude=True)
    assert (r.chosen, r.ambiguous, r.resolved_by) == (0, False, "error_ratio")


def test_both_agree_previous_pose_decides_else_ambiguous() -> None:
    # normals 1 and 1.5 deg off the attitude's (both agree, neither closer by the 3 deg margin),
    # the poses 20 deg apart about the optical axis
    truth = rot_z(math.radians(20.0)) @ rot_y(math.radians(1.0)) @ DOWN
    mirror = rot_y(math.radians(-1.5)) @ DOWN
    c = [_cand(mirror, 0.30), _cand(truth, 0.30)]
    up = np.array([0.0, 0.0, -1.0])
    r = resolve_ambiguity(c, CFG, up_cam=up, attitude=True)
    assert (r.ambiguous, r.resolved_by) == (True, "attitude_both")
    r = resolve_ambiguity(c, CFG, up_cam=up, prior_R=rot_x(math.radians(1.0)) @ truth, attitude=True)
    assert (r.chosen, r.ambiguous, r.resolved_by) == (1, False, "previous")


def test_both_agree_the_closer_one_by_the_margin_wins() -> None:
    truth, mirror = _pair(0.5, 6.5)  # both within 8 deg, the truth 6 deg closer
    r = resolve_ambiguity([_cand(mirror, 0.3), _cand(truth, 0.3)], CFG, up_cam=_up_for(truth), attitude=True)
    assert (r.chosen, r.ambiguous, r.resolved_by) == (1, False, "attitude")


def test_attitude_and_previous_pose_disagreeing_is_ambiguous() -> None:
    truth, mirror = _pair(5.0, -10.0)
    c = [_cand(truth, 0.30), _cand(mirror, 0.31)]
    r = resolve_ambiguity(c, CFG, up_cam=_up_for(truth), prior_R=mirror, attitude=True)
    assert (r.ambiguous, r.resolved_by) == (True, "conflict_attitude_previous")


def test_down_in_camera_and_marker_normal() -> None:
    R_bc = rot_z(math.pi / 2)  # the downward mount of companion_sitl.camera
    np.testing.assert_allclose(down_in_camera(np.eye(3), R_bc), [0.0, 0.0, 1.0], atol=1e-12)
    # nose up 10 deg: down leans 10 deg towards the image bottom (camera +y is the vehicle's back)
    d = down_in_camera(euler_to_rotmat(0.0, math.radians(10.0), 0.0), R_bc)
    assert math.degrees(math.acos(d[2])) == pytest.approx(10.0) and d[1] > 0 and abs(d[0]) < 1e-12
    # a level pad: its normal (world up) is minus down
    np.testing.assert_allclose(marker_normal_in_camera(R_bc, np.array([0.0, 0.0, -2.0])), [0, 0, -1], atol=1e-12)
    with pytest.raises(ValueError, match="finite 3x3"):
        down_in_camera(np.full((3, 3), np.nan), R_bc)
    with pytest.raises(ValueError, match="3-vector"):
        marker_normal_in_camera(np.eye(3), np.array([1.0, 0.0]))


def test_config_rejects_a_bad_attitude_threshold() -> None:
    with pytest.raises(ValueError, match="attitude_agree_rad"):
        DetectorConfig(attitude_agree_rad=0.0)
    with pytest.raises(ValueError, match="attitude_margin_rad"):
        DetectorConfig(attitude_margin_rad=float("nan"))
