"""The parcel's tag seen from above (companion.vision.parcel_tag) in frames the simulated camera
renders with the parcel painted in (companion_sitl.camera_parcel): found, and its bottom placed
above the pad from the vehicle's pose, over drawn poses and heights."""

from __future__ import annotations

import numpy as np
import pytest

from companion.geometry import Transform
from companion.geometry.mounts import downward_mount, pad_pose_ned
from companion.vision.camera import load_default_camera
from companion.vision.pad import PadLayout
from companion.vision.parcel_tag import ParcelTagFinder, parcel_bottom_above_pad_m, tag_clashes_with_pad
from companion_sitl.camera import SimCameraConfig, SimulatedCamera
from companion_sitl.camera_parcel import ParcelLook, ParcelPainter

CAM = load_default_camera()
MOUNT = downward_mount((0.0, 0.0, 0.1))


def _frame(seed: int, T_wb: Transform, bottom_ned: tuple[float, float, float], look: ParcelLook) -> np.ndarray:
    sim = SimulatedCamera(
        CAM,
        PadLayout(),
        SimCameraConfig(noise_std=2.0),
        T_body_camera=MOUNT,
        T_world_pad=pad_pose_ned(0, 0, 0),
        seed=seed,
    )
    T_wc = sim.T_world_camera(T_wb)
    img = sim.expose(sim.render_optics(T_wc.inverse() @ sim.T_world_pad, fresh=True))
    return ParcelPainter(look).paint(img, CAM, T_wc, bottom_ned)


def test_drawn_hovers_and_heights_place_the_parcel_within_a_few_centimetres() -> None:
    rng = np.random.default_rng(58)
    finder = ParcelTagFinder(CAM, "DICT_4X4_50", 7, 0.2)
    errs = []
    for k in range(24):
        hover = rng.uniform(4.0, 6.0)
        roll, pitch, yaw = rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(-3.1, 3.1)
        T_wb = Transform.from_euler([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), -hover], roll, pitch, yaw)
        bottom = rng.choice([0.0, rng.uniform(0.0, hover - 1.5)])  # on the pad, or hanging
        off = rng.uniform(-0.25, 0.25, 2)  # the parcel swings a little off the vertical
        where = (float(T_wb.t[0] + off[0]), float(T_wb.t[1] + off[1]), -float(bottom))
        tag = finder.find(_frame(k, T_wb, where, ParcelLook(tag_id=7)))
        assert tag is not None, (k, hover, bottom)
        got = parcel_bottom_above_pad_m(tag, T_wb.t, (roll, pitch, yaw), MOUNT, 0.0, 0.25)
        errs.append(abs(got - bottom))
        # the tag's range error grows with its range: a few percent of it at worst
        assert abs(got - bottom) < 0.02 + 0.015 * (hover - bottom), (k, hover, bottom, got)
    assert np.median(errs) < 0.03


def test_a_plain_box_or_another_tag_is_not_the_parcel() -> None:
    T_wb = Transform.from_euler([0.0, 0.0, -5.0], 0.0, 0.0, 0.0)
    finder = ParcelTagFinder(CAM, "DICT_4X4_50", 7, 0.2)
    assert finder.find(_frame(1, T_wb, (0.0, 0.0, 0.0), ParcelLook(tag_id=-1))) is None
    assert finder.find(_frame(1, T_wb, (0.0, 0.0, 0.0), ParcelLook(tag_id=8))) is None
    assert finder.find(_frame(1, T_wb, (0.0, 0.0, 0.0), ParcelLook(tag_id=7))) is not None
    assert (finder.frames, finder.found) == (3, 1)


def test_a_parcel_just_under_the_lens_is_not_drawn() -> None:
    T_wb = Transform.from_euler([0.0, 0.0, -5.0], 0.0, 0.0, 0.0)
    sim = SimulatedCamera(CAM, PadLayout(), T_body_camera=MOUNT, T_world_pad=pad_pose_ned(0, 0, 0), seed=0)
    T_wc = sim.T_world_camera(T_wb)
    img = sim.render(T_wc.inverse() @ sim.T_world_pad)
    out = ParcelPainter(ParcelLook(tag_id=7)).paint(img, CAM, T_wc, (0.0, 0.0, -4.6))  # top 0.05 m from the lens
    assert out is img


def test_tag_clashes_and_bad_tags_are_refused() -> None:
    pad = PadLayout()
    assert tag_clashes_with_pad(pad, "DICT_4X4_50", 0) == "the parcel tag DICT_4X4_50 id 0 is the pad's inner marker"
    assert tag_clashes_with_pad(pad, "DICT_5X5_50", 0) == "the parcel tag DICT_5X5_50 id 0 is the pad's outer marker"
    assert tag_clashes_with_pad(pad, "DICT_4X4_50", 7) == ""
    with pytest.raises(ValueError, match=r"parcel tag id 50: must be an integer in \[0, 50\)"):
        ParcelTagFinder(CAM, "DICT_4X4_50", 50, 0.2)
    with pytest.raises(ValueError, match="parcel tag size"):
        ParcelTagFinder(CAM, "DICT_4X4_50", 7, float("nan"))
    with pytest.raises(ValueError, match=r"must fit on the 0\.3 m top"):
        ParcelLook(tag_id=7, tag_size_m=0.25)
