"""The drop-zone check's flight side (companion.delivery.drop_zone_watch): the pose it judges a
frame on, and the verdict the mission gets."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from companion.config import DropZoneConfig
from companion.delivery.drop_zone_watch import DropZoneWatch, detector_pose, predicted_camera_pad
from companion.estimation.types import StateEstimate
from companion.geometry import Transform
from companion.geometry.mounts import downward_mount, pad_pose_ned
from companion.vision.camera import load_default_camera
from companion.vision.drop_zone import DropZoneVerdict
from companion.vision.pad import PadLayout
from companion_sitl.camera import SimulatedCamera


@dataclass
class _Fusion:
    """What the watch reads of the landing fusion."""

    est: StateEstimate | None
    pad_locked: bool
    T_world_pad: Transform

    def estimate(self) -> StateEstimate | None:
        return self.est


def _estimate(n: float, e: float, d: float, roll: float, pitch: float, yaw: float) -> StateEstimate:
    return StateEstimate(1.0, n, e, d, 0.0, 0.0, 0.0, roll, pitch, yaw)


def test_the_predicted_pose_is_the_pad_seen_from_the_estimate() -> None:
    mount = downward_mount()
    T_world_pad = pad_pose_ned(2.0, -1.0, 0.0, yaw_rad=0.4)
    est = _estimate(2.3, -0.8, -4.0, 0.05, -0.03, 1.1)
    got = predicted_camera_pad(_Fusion(est, True, T_world_pad), mount)
    assert got is not None
    # the pad centre seen from the camera, computed the long way round
    T_wb = Transform.from_euler([2.3, -0.8, -4.0], 0.05, -0.03, 1.1)
    cam_in_world = T_wb @ mount
    centre_cam = cam_in_world.inverse().apply(np.array([[2.0, -1.0, 0.0]]))[0]
    assert np.allclose(got.t, centre_cam, atol=1e-9)
    assert got.t[2] == pytest.approx(4.0, abs=0.3)  # about 4 m in front of a downward camera


def test_no_predicted_pose_before_the_pad_is_locked() -> None:
    est = _estimate(0.0, 0.0, -5.0, 0.0, 0.0, 0.0)
    pad = pad_pose_ned(0.0, 0.0, 0.0)
    assert predicted_camera_pad(_Fusion(est, False, pad), downward_mount()) is None
    assert predicted_camera_pad(_Fusion(None, True, pad), downward_mount()) is None
    assert predicted_camera_pad(None, downward_mount()) is None


@dataclass
class _Obs:
    markers: tuple[str, ...]
    ambiguous: bool = False
    T_camera_pad: Transform = field(default_factory=Transform.identity)


def test_only_an_unambiguous_outer_marker_pose_serves_the_check() -> None:
    assert detector_pose(None) is None
    assert detector_pose(_Obs(("inner",))) is None
    assert detector_pose(_Obs(("outer", "inner"), ambiguous=True)) is None
    assert detector_pose(_Obs(("outer",))) is not None


def _frames(cfg: DropZoneConfig):  # type: ignore[no-untyped-def]
    cam = load_default_camera()
    layout = PadLayout()
    sim = SimulatedCamera(cam, layout, seed=3)
    T_wb = Transform.from_euler([0.0, 0.0, -4.0], 0.0, 0.0, 0.3)
    T_cp = sim.T_camera_pad(T_wb)
    return cam, layout, sim, T_cp


def test_a_clear_pad_judged_is_clear_and_the_verdict_goes_stale() -> None:
    cfg = DropZoneConfig(enabled=True)
    cam, layout, sim, T_cp = _frames(cfg)
    watch = DropZoneWatch(cam, layout, cfg)
    assert watch.verdict(0.0) is DropZoneVerdict.UNKNOWN  # nothing judged yet
    t = 0.0
    for k in range(cfg.votes + 2):
        t = k / 30.0
        img = sim.expose(sim.render_optics(T_cp, fresh=True))
        st = watch.judge(img, t, None, T_cp)
        assert st is not None
    assert watch.verdict(t) is DropZoneVerdict.CLEAR
    assert watch.frames_predicted == watch.frames_judged == cfg.votes + 2
    assert watch.verdict(t + cfg.stale_s + 0.01) is DropZoneVerdict.UNKNOWN
    # no pose from either side: the frame is not judged
    assert watch.judge(img, t + 2.0, None, None) is None
    watch.reset()
    assert watch.verdict(t) is DropZoneVerdict.UNKNOWN


def test_a_box_on_the_pad_is_occupied() -> None:
    from companion_sitl.camera_occluders import Occluder

    cfg = DropZoneConfig(enabled=True)
    cam, layout, sim, T_cp = _frames(cfg)
    box = Occluder("box", (0.1, -0.1), (0.4, 0.35), 0.25, 0.5, 150)
    watch = DropZoneWatch(cam, layout, cfg)
    for k in range(cfg.votes):
        t = k / 30.0
        img = sim.expose(box.paint(sim.render_optics(T_cp, fresh=True), cam, T_cp, t))
        watch.judge(img, t, None, T_cp)
    assert watch.verdict(t) is DropZoneVerdict.OCCUPIED
