"""A real camera's images (companion_sitl.camera_conditions, [sim.camera]): each effect does what
its parameter says on synthetic images, every draw comes from its own stream (the camera's noise
is the same with or without them), all off is no change; the driver's drops and delays at their
rates; a delivery flown with params/camera_real.toml lands on the pad."""

from __future__ import annotations

import numpy as np
import pytest

from companion.config import shipped_params_path
from companion.vision.camera import load_default_camera
from companion.vision.pad import PadLayout
from companion_sitl.camera import SimCameraConfig, SimulatedCamera
from companion_sitl.camera_conditions import (
    CONDITION_KEYS,
    CameraConditions,
    condition_tables,
    jpeg,
    motion_blur,
    pad_velocity_px_s,
    rolling_shutter,
)
from companion_sitl.params import SimCameraConditionsConfig, load_simulated_config


def _edge(h: int = 120, w: int = 160, x0: int = 80) -> np.ndarray:
    img = np.full((h, w), 40, np.uint8)
    img[:, x0:] = 220
    return img


def _edge_width(row: np.ndarray) -> int:
    """Pixels between 10 % and 90 % of the way from dark to bright."""
    lo, hi = 40 + 0.1 * 180, 40 + 0.9 * 180
    return int(np.count_nonzero((row > lo) & (row < hi)))


def test_all_off_is_inactive_and_changes_nothing():
    c = CameraConditions(SimCameraConditionsConfig(), seed=3)
    assert not c.active
    img = _edge()
    assert c.motion(img, (500.0, 200.0)) is img and c.photometric(img, 1.0) is img


def test_motion_blur_smears_along_the_motion_only():
    img = _edge()
    across = motion_blur(img, 12.0, 0.0)  # the edge is vertical: motion along u blurs it
    along = motion_blur(img, 0.0, 12.0)  # motion along v slides it along itself: unchanged
    assert 9 <= _edge_width(across[60].astype(float)) <= 13
    assert _edge_width(along[60].astype(float)) == 0
    assert motion_blur(img, 0.4, 0.3) is img  # under a pixel: no blur


def test_the_rolling_shutter_shears_rows_by_their_read_delay():
    img = _edge()
    out = rolling_shutter(img, vu_px_s=300.0, vv_px_s=0.0, readout_s=0.02)

    def edge_x(row: np.ndarray) -> float:
        return float(np.argmax(row > 130))

    assert edge_x(out[0]) == pytest.approx(80, abs=1)  # the first row is read at once
    # the last row 0.02 * 119/120 s later: the scene moved 300 px/s * that = 5.95 px
    assert edge_x(out[-1]) == pytest.approx(80 + 300 * 0.02 * 119 / 120, abs=1.0)


def test_jpeg_keeps_the_picture_and_adds_artefacts():
    rng = np.random.default_rng(0)
    img = np.clip(_edge().astype(float) + rng.normal(0, 8, (120, 160)), 0, 255).astype(np.uint8)
    q70, q100 = jpeg(img, 70), jpeg(img, 100)
    assert q70.shape == img.shape and q70.dtype == np.uint8
    assert abs(float(q70.mean()) - float(img.mean())) < 1.5
    assert 0.5 < float(np.abs(q70.astype(int) - img).mean()) < 10  # the noise compressed away, blocks added
    assert float(np.abs(q100.astype(int) - img).mean()) < float(np.abs(q70.astype(int) - img).mean())


def test_auto_exposure_steps_dim_the_frame_and_recover():
    cfg = SimCameraConditionsConfig(exposure_steps_s=3.0, exposure_step_gain=0.4, exposure_recover_s=0.5)
    c = CameraConditions(cfg, seed=1)
    flat = np.full((40, 40), 200, np.uint8)
    ts = np.arange(0.0, 300.0, 0.05)
    means = np.array([float(c.photometric(flat, float(t)).mean()) for t in ts])
    dim = means < 199.5
    assert means.min() == pytest.approx(200 * 0.4, abs=1.0)  # the step's depth
    # steps every 3 s on average, each dims the frame for up to 0.5 s: a sixth of the time at most
    starts = np.count_nonzero(dim[1:] & ~dim[:-1])
    assert 70 <= starts <= 130, starts
    assert 0.05 < dim.mean() < 0.17, dim.mean()


def test_the_shadow_band_darkens_part_of_the_frame_by_its_factor():
    c = CameraConditions(SimCameraConditionsConfig(shadow=0.6), seed=2)
    flat = np.full((120, 160), 200, np.uint8)
    shares = []
    for t in np.arange(0.0, 20.0, 1.0):
        out = c.photometric(flat, float(t))
        dark = out < 199
        shares.append(dark.mean())
        if dark.any():
            assert np.all(np.abs(out[dark].astype(int) - 80) <= 1)  # 200 * (1 - 0.6)
    assert 0.1 < float(np.mean(shares)) < 0.6  # a band across the frame, moving


def test_glare_and_low_light_noise():
    flat = np.full((120, 160), 100, np.uint8)
    g = CameraConditions(SimCameraConditionsConfig(glare=60.0), seed=4).photometric(flat, 0.0)
    assert g.max() == pytest.approx(160, abs=1) and g.min() >= 100
    n = CameraConditions(SimCameraConditionsConfig(low_light_noise=5.0), seed=4).photometric(flat, 0.0)
    assert float(np.std(n.astype(float))) == pytest.approx(5.0, rel=0.1)


def test_the_driver_drops_and_delays_frames_at_their_rates():
    c = CameraConditions(SimCameraConditionsConfig(drop_fraction=0.1, late_s=0.04), seed=5)
    fates = [c.fate() for _ in range(4000)]
    assert sum(f.dropped for f in fates) / 4000 == pytest.approx(0.1, abs=0.015)
    late = [f.extra_latency_s for f in fates]
    assert min(late) >= 0.0 and max(late) <= 0.04 and np.mean(late) == pytest.approx(0.02, abs=0.002)
    assert c.dropped == sum(f.dropped for f in fates)


def test_the_camera_s_own_noise_is_the_same_with_the_conditions_on():
    cam, layout = load_default_camera(), PadLayout()
    frames = []
    for cond in (SimCameraConditionsConfig(), SimCameraConditionsConfig(low_light_noise=3.0, drop_fraction=0.2)):
        sim = SimulatedCamera(cam, layout, SimCameraConfig(noise_std=2.0, gain_jitter=0.03), seed=9)
        c = CameraConditions(cond, seed=9)
        optics = np.full((cam.height_px, cam.width_px), 120, np.uint8)
        seq = []
        for k in range(3):
            c.fate()
            c.photometric(optics, k / 30)
            seq.append(sim.expose(optics))  # the camera's exposure: its own generator only
        frames.append(seq)
    for a, b in zip(*frames, strict=True):
        assert np.array_equal(a, b)


def test_the_pad_s_image_velocity():
    # the pad 10 m below, moving 0.5 m along the camera's x in 0.1 s: fx * 0.5 / 10 / 0.1 px/s
    v = pad_velocity_px_s(500.0, 500.0, 320.0, 240.0, np.array([0.0, 0.0, 10.0]), np.array([0.5, 0.0, 10.0]), 0.1)
    assert v == pytest.approx((250.0, 0.0))
    assert pad_velocity_px_s(500.0, 500.0, 320.0, 240.0, None, np.array([0.5, 0.0, 10.0]), 0.1) == (0.0, 0.0)


def test_each_condition_s_table_is_camera_real_s_level():
    tables = condition_tables()
    assert set(tables) == {*CONDITION_KEYS, "all"}
    for name, keys in CONDITION_KEYS.items():
        assert set(tables[name]) == set(keys) and all(tables["all"][k] == v for k, v in tables[name].items())
    config = load_simulated_config(shipped_params_path("sitl_short.toml"), shipped_params_path("camera_real.toml"))
    assert CameraConditions(config.sim.camera, 1).active


@pytest.mark.flight
def test_a_delivery_with_a_real_camera_s_images_lands_on_the_pad():
    """params/camera_real.toml over sitl_short: every condition at once, the delivery still fused
    onto the pad (the pad lock and the gates keep a bad frame out)."""
    from companion_lab.demo import run_demo

    config = load_simulated_config(shipped_params_path("sitl_short.toml"), shipped_params_path("camera_real.toml"))
    r = run_demo(config, fusion=True)
    assert r.delivered and r.returned, r
    assert r.pad_landing_error_m < 0.1, r.pad_landing_error_m
