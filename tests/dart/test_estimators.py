"""Dart position estimators FCF-CF, FCF-MF, SCF-MF-2DOF, SCF-MF-3DOF (dart eqs 14-21)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.dart.estimators import (
    ESTIMATORS,
    CameraMarkerObservation,
    DartEstimator,
    DartEstimatorConfig,
    DartTaskRates,
    FcfCfEstimator,
    GimbalKind,
    MadgwickPositionEstimator,
    ScfMf2DofEstimator,
    camera_mount,
    corrected_sample_std,
    dart_r_xyz,
    dart_r_z,
    ground_marker,
    make_estimator,
    wall_marker,
)
from companion.estimation.complementary import ComplementaryConfig
from companion.estimation.madgwick import MadgwickConfig
from companion.geometry import euler_to_quat, euler_to_rotmat, rot_x, rot_y, rot_z, rotmat_to_euler

G = 9.80665
NO_LEVER = (0.0, 0.0, 0.0)


def accel_at_rest(R_wb: np.ndarray) -> tuple[float, float, float]:
    f = R_wb.T @ np.array([0.0, 0.0, -G])
    return (float(f[0]), float(f[1]), float(f[2]))


def seed_attitude(est: DartEstimator, rpy: tuple[float, float, float], t0: float = 0.0, n: int = 3) -> None:
    """Put an exact attitude into an estimator's Madgwick filter and its history."""
    assert isinstance(est, MadgwickPositionEstimator)
    est.madgwick.reset(tuple(euler_to_quat(*rpy)))
    R = euler_to_rotmat(*rpy)
    for k in range(n):
        est.update_imu(t0 + 0.005 * k, (0.0, 0.0, 0.0), accel_at_rest(R))


def observe(
    cfg: DartEstimatorConfig,
    R_wb: np.ndarray,
    p_w: np.ndarray,
    R_wc: np.ndarray | None = None,
    t: float = 0.0,
    marker_w: np.ndarray | None = None,
) -> CameraMarkerObservation:
    """The exact PnP result for a drone (CoT at p_w, attitude R_wb) and a marker at marker_w."""
    R_bc = np.array(cfg.R_body_cam)
    R_wm = np.array(cfg.R_world_marker)
    if R_wc is None:
        R_wc = R_wb @ R_bc
    m = np.zeros(3) if marker_w is None else marker_w
    cam_w = p_w + R_wb @ np.array(cfg.t_body_cam_m)
    return CameraMarkerObservation(t, R_wc.T @ R_wm, R_wc.T @ (m - cam_w))


# --------------------------------------------------------------------- paper matrices
def test_eq17_and_eq20_matrices() -> None:
    # hand case: phi = pi/2, theta = psi = 0 -> c_phi = 0, s_phi = 1:
    #   row 1: [c_phi c_psi, c_phi s_psi s_theta + s_phi c_theta, ...] = [0, 1, 0]
    #   row 2: [-s_phi c_psi, ..., ...]                                  = [-1, 0, 0]
    #   row 3: [s_psi, -c_psi s_theta, c_psi c_theta]                    = [0, 0, 1]
    assert np.allclose(dart_r_xyz(math.pi / 2, 0.0, 0.0), [[0, 1, 0], [-1, 0, 0], [0, 0, 1]])
    rng = np.random.default_rng(3)
    for _ in range(10):
        phi, theta, psi = rng.uniform(-3, 3, 3)
        R = dart_r_xyz(phi, theta, psi)
        assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
        assert np.allclose(R, (rot_x(theta) @ rot_y(psi) @ rot_z(phi)).T)
        assert np.allclose(dart_r_z(psi), rot_z(psi).T)
    # eq 20 hand case: psi = pi/2 -> [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]
    assert np.allclose(dart_r_z(math.pi / 2), [[0, 1, 0], [-1, 0, 0], [0, 0, 1]])


def test_frame_helpers() -> None:
    fwd = np.array(camera_mount())
    # forward camera: optical axis (cam z) = body x, image right (cam x) = body y
    assert np.allclose(fwd[:, 2], [1, 0, 0]) and np.allclose(fwd[:, 0], [0, 1, 0])
    down = np.array(camera_mount(pitch_rad=-math.pi / 2))
    assert np.allclose(down[:, 2], [0, 0, 1])
    wall = np.array(wall_marker(0.0))
    # marker x = east, y = up, z = south (towards a drone heading north)
    assert np.allclose(wall.T, [[0, 1, 0], [0, 0, -1], [-1, 0, 0]])
    assert np.allclose(np.array(ground_marker(0.0))[:, 2], [0, 0, -1])


# ----------------------------------------------------------------- hand-computed cases
def test_eq16_fcf_mf_and_fcf_cf_by_hand() -> None:
    # Drone level, heading north, forward camera, lens 0.1 m ahead of and 0.05 m below the CoT
    # (t_body_cam = (0.1, 0, 0.05) FRD). Wall marker at the NED origin facing the drone; the
    # CoT at NED (-4, 0.5, -0.3): 4 m in front of the marker, 0.5 m to its right, 0.3 m above.
    # Camera at (-3.9, 0.5, -0.25); marker relative to the camera, NED: (3.9, -0.5, 0.25);
    # in camera axes (x = east, y = down, z = north):      Q_m   = (-0.5, 0.25, 3.9)
    # Q_off = R_body_cam^T t_body_cam = (body y, body z, body x) = (0, 0.05, 0.1)
    # Q_ct = Q_m + Q_off                                           = (-0.5, 0.30, 4.0)
    # R(Phi) = R_marker_cam: cam x = marker x, cam y = -marker y, cam z = -marker z -> diag(1,-1,-1)
    # eq 16: Q_hat = R(Phi) Q_ct = (-0.5, -0.30, -4.0); the drone in the marker frame is -Q_hat:
    expected = (0.5, 0.30, 4.0)
    cfg = DartEstimatorConfig(t_body_cam_m=(0.1, 0.0, 0.05))
    obs = CameraMarkerObservation(0.01, np.diag([1.0, -1.0, -1.0]), np.array([-0.5, 0.25, 3.9]), marker_id=7)
    mf = make_estimator("FCF-MF", cfg)
    seed_attitude(mf, (0.0, 0.0, 0.0))
    est = mf.update_vision(obs)
    assert est is not None and est.method == "FCF-MF" and est.marker_id == 7
    assert (est.x_m, est.y_m, est.z_m) == pytest.approx(expected, abs=1e-12)
    assert est.yaw_rad == pytest.approx(0.0)

    cf = make_estimator("FCF-CF", cfg)
    est = cf.update_vision(obs)  # the first frame initialises the complementary filter
    assert est is not None
    assert (est.x_m, est.y_m, est.z_m) == pytest.approx(expected, abs=1e-12)


def test_eq19_scf_mf_2dof_by_hand() -> None:
    # Drone heading east (yaw pi/2) and pitched nose-down 0.2 rad; the 2-DOF gimbal keeps the
    # camera level, looking east. Wall marker facing the drone: wall_marker(pi/2), marker
    # x = south, y = up, z = west. CoT at NED (0, -4, 0), marker at the origin, lens
    # t_body_cam = (0.1, 0, 0.05).
    # Lever arm in the world, R_XYZ(Phi_hat) Q_off = Rz(pi/2) Ry(-0.2) (0.1, 0, 0.05):
    #   Ry(-0.2) (0.1, 0, 0.05) = (0.1 c - 0.05 s, 0, 0.1 s + 0.05 c), c = 0.980067, s = 0.198669
    #                           = (0.088074, 0, 0.068870)
    #   Rz(pi/2) (x, y, z) = (-y, x, z)                     = (0, 0.088074, 0.068870)
    # camera at (0, -3.911926, 0.068870); marker relative to it, NED: (0, 3.911926, -0.068870);
    # level camera looking east: x = south, y = down, z = east ->
    #   Q_m = (0, -0.068870, 3.911926)
    # eq 19: R_Z(psi) Q_m brings Q_m back to NED (0, 3.911926, -0.068870); adding the lever arm
    # gives the marker relative to the CoT, (0, 4, 0); in marker axes (x south, y up, z west)
    # that is (0, 0, -4), and the drone is its negative:
    expected = (0.0, 0.0, 4.0)
    c, s = math.cos(0.2), math.sin(0.2)
    lever = (0.1 * c - 0.05 * s, 0.1 * s + 0.05 * c)
    assert lever == pytest.approx((0.088074, 0.068870), abs=1e-6)
    q_m = np.array([0.0, -lever[1], 4.0 - lever[0]])
    cfg = DartEstimatorConfig(t_body_cam_m=(0.1, 0.0, 0.05), R_world_marker=wall_marker(math.pi / 2))
    est2 = make_estimator("scf_mf_2dof", cfg)
    assert isinstance(est2, ScfMf2DofEstimator) and est2.gimbal is GimbalKind.TWO_DOF
    seed_attitude(est2, (0.0, -0.2, math.pi / 2))
    # the camera is level: R_cam_marker does not contain the pitch; it is not used by eq 19
    R_wc = rot_z(math.pi / 2) @ np.array(cfg.R_body_cam)
    obs = CameraMarkerObservation(0.01, R_wc.T @ np.array(cfg.R_world_marker), q_m)
    est = est2.update_vision(obs)
    assert est is not None
    assert (est.x_m, est.y_m, est.z_m) == pytest.approx(expected, abs=1e-12)
    assert est.pitch_rad == pytest.approx(-0.2) and est.yaw_rad == pytest.approx(math.pi / 2)

    # FCF-MF on the same numbers would rotate Q_m by the pitch as well, which is wrong for a
    # stabilised camera: about 4 m * sin(0.2) = 0.8 m of error in height
    fcf = make_estimator("FCF-MF", cfg)
    seed_attitude(fcf, (0.0, -0.2, math.pi / 2))
    wrong = fcf.update_vision(obs)
    assert wrong is not None and abs(wrong.y_m) > 0.7


def test_eq21_scf_mf_3dof_by_hand() -> None:
    # The 3-DOF gimbal holds the camera level, looking north (gimbal_yaw 0), while the drone
    # is yawed 0.5 rad. Wall marker at the origin facing north-bound drones, CoT at (-4, 0, 0),
    # lens t_body_cam = (0.1, 0, 0).
    # lever arm in NED, R_XYZ(Phi_hat) Q_off = (0.1 cos 0.5, 0.1 sin 0.5, 0) = (0.087758, 0.047943, 0)
    # camera at (-3.912242, 0.047943, 0); marker relative to it: (3.912242, -0.047943, 0);
    # camera axes (x east, y down, z north):  Q_m = (-0.047943, 0, 3.912242)
    # eq 21: Q_m + lever arm (camera axes: (0.047943, 0, 0.087758)) = (0, 0, 4): the marker is
    # 4 m ahead along the optical axis = -marker z, so the drone is at (0, 0, 4) in the marker frame.
    expected = (0.0, 0.0, 4.0)
    cfg = DartEstimatorConfig(t_body_cam_m=(0.1, 0.0, 0.0), gimbal_yaw_rad=0.0)
    q_m = np.array([-0.1 * math.sin(0.5), 0.0, 4.0 - 0.1 * math.cos(0.5)])
    assert q_m == pytest.approx([-0.047943, 0.0, 3.912242], abs=1e-6)
    est3 = make_estimator("SCF-MF-3DOF", cfg)
    assert est3.gimbal is GimbalKind.THREE_DOF
    seed_attitude(est3, (0.1, 0.0, 0.5))  # roll does not matter: the lever arm has no y/z part
    obs = CameraMarkerObservation(0.01, np.diag([1.0, -1.0, -1.0]), q_m)
    est = est3.update_vision(obs)
    assert est is not None
    assert (est.x_m, est.y_m, est.z_m) == pytest.approx(expected, abs=1e-12)


# ------------------------------------------------------------------ general geometry
@pytest.mark.parametrize("name", sorted(ESTIMATORS))
@pytest.mark.parametrize("mount", ["forward-wall", "down-ground"])
def test_exact_inputs_give_exact_position(name: str, mount: str) -> None:
    rng = np.random.default_rng(11)
    if mount == "forward-wall":
        cfg = DartEstimatorConfig(t_body_cam_m=(0.07, -0.02, 0.04), gimbal_yaw_rad=0.3)
    else:
        cfg = DartEstimatorConfig(
            R_body_cam=camera_mount(pitch_rad=-math.pi / 2),
            R_world_marker=ground_marker(0.4),
            t_body_cam_m=(0.02, 0.01, 0.06),
            gimbal_yaw_rad=0.3,
        )
    R_bc = np.array(cfg.R_body_cam)
    R_wm = np.array(cfg.R_world_marker)
    for trial in range(5):
        rpy = (rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-0.5, 0.5))
        if mount == "forward-wall":
            p_w = np.array([-rng.uniform(2, 6), rng.uniform(-1, 1), rng.uniform(-1, 1)])
        else:
            p_w = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), -rng.uniform(2, 8)])
        R_wb = euler_to_rotmat(*rpy)
        gimbal = ESTIMATORS[name].gimbal
        if gimbal is GimbalKind.TWO_DOF:
            R_wc = rot_z(rpy[2]) @ R_bc
        elif gimbal is GimbalKind.THREE_DOF:
            R_wc = rot_z(0.3) @ R_bc
        else:
            R_wc = R_wb @ R_bc
        est = make_estimator(name, cfg)
        t0 = 10.0 * trial
        if name != "FCF-CF":
            seed_attitude(est, rpy, t0)
        out = est.update_vision(observe(cfg, R_wb, p_w, R_wc, t=t0 + 0.01))
        assert out is not None
        truth = R_wm.T @ p_w
        assert (out.x_m, out.y_m, out.z_m) == pytest.approx(tuple(truth), abs=1e-9)
        assert (out.roll_rad, out.pitch_rad, out.yaw_rad) == pytest.approx(rpy, abs=1e-9)


def test_uses_the_attitude_at_the_exposure_time() -> None:
    # the drone yaws at 0.5 rad/s; the frame was exposed 60 ms before the newest IMU sample
    cfg = DartEstimatorConfig(madgwick=MadgwickConfig(gamma=0.0))  # pure gyro: exact yaw
    est = make_estimator("FCF-MF", cfg)
    assert isinstance(est, MadgwickPositionEstimator)
    rate = 0.5
    for k in range(60):
        t = k * 0.005
        est.update_imu(t, (0.0, 0.0, rate), (0.0, 0.0, -G))
    t_exp = 59 * 0.005 - 0.06
    yaw_exp = rate * t_exp
    p_w = np.array([-4.0, 0.2, -0.1])
    out = est.update_vision(observe(cfg, euler_to_rotmat(0.0, 0.0, yaw_exp), p_w, t=t_exp))
    assert out is not None
    assert out.yaw_rad == pytest.approx(yaw_exp, abs=1e-4)
    assert (out.x_m, out.y_m, out.z_m) == pytest.approx((0.2, 0.1, 4.0), abs=2e-3)
    # with the newest attitude instead, the 0.03 rad of yaw would move x by ~0.12 m
    late = est.madgwick.euler()[2]
    assert late - yaw_exp == pytest.approx(0.03, abs=1e-3)


def test_fcf_cf_filters_noisy_vision_attitude() -> None:
    # hovering with small attitude oscillations, exact gyro, vision rotation noise ~1 deg:
    # the complementary filter's position is less noisy than the one from the raw rotation
    rng = np.random.default_rng(5)
    cfg = DartEstimatorConfig(complementary=ComplementaryConfig(lam=0.9))
    est = FcfCfEstimator(cfg)
    R_bc = np.array(cfg.R_body_cam)
    R_wm = np.array(cfg.R_world_marker)
    p_w = np.array([-4.0, 0.0, 0.0])
    truth = R_wm.T @ p_w

    def rpy_at(t: float) -> tuple[float, float, float]:
        return (0.1 * math.sin(2 * t), 0.1 * math.cos(1.5 * t), 0.1 * math.sin(2.5 * t))

    def body_rates(t: float, h: float = 1e-5) -> np.ndarray:
        R0, R1 = euler_to_rotmat(*rpy_at(t - h)), euler_to_rotmat(*rpy_at(t + h))
        W = R0.T @ (R1 - R0) / (2 * h)  # ~ skew(omega) (first order)
        return np.array([W[2, 1], W[0, 2], W[1, 0]])

    filtered, raw, att_filtered, att_raw = [], [], [], []
    for k in range(1, 1200):  # 6 s of IMU at 200 Hz, vision every 7th sample (~29 Hz)
        t = k * 0.005
        est.update_imu(t, tuple(body_rates(t - 0.0025)), (0.0, 0.0, -G))
        if k % 7 == 0:
            R_wb = euler_to_rotmat(*rpy_at(t))
            obs = observe(cfg, R_wb, p_w, t=t)
            noise = euler_to_rotmat(*rng.normal(0.0, 0.017, 3))
            R_noisy = noise @ obs.R_cam_marker
            out = est.update_vision(CameraMarkerObservation(t, R_noisy, obs.t_cam_marker_m))
            assert out is not None
            if t > 1.0:
                filtered.append(np.array([out.x_m, out.y_m, out.z_m]) - truth)
                q_ct = obs.t_cam_marker_m + R_bc.T @ np.array(cfg.t_body_cam_m)
                raw.append(-(R_noisy.T @ q_ct) - truth)
                true_rpy = np.array(rpy_at(t))
                att_filtered.append(np.array([out.roll_rad, out.pitch_rad, out.yaw_rad]) - true_rpy)
                R_wb_raw = R_wm @ R_noisy.T @ R_bc.T
                att_raw.append(np.array(rotmat_to_euler(R_wb_raw)) - true_rpy)
    rms_filtered = math.sqrt(np.mean(np.sum(np.square(filtered), axis=1)))
    rms_raw = math.sqrt(np.mean(np.sum(np.square(raw), axis=1)))
    assert rms_filtered < 0.6 * rms_raw
    assert np.abs(np.mean(filtered, axis=0)).max() < 0.02
    # and the body attitude (roll about the optical axis does not move the position)
    for axis in range(3):
        a_f = np.array(att_filtered)[:, axis]
        a_r = np.array(att_raw)[:, axis]
        assert math.sqrt(np.mean(a_f**2)) < 0.6 * math.sqrt(np.mean(a_r**2))


def test_vision_yaw_alignment_optional() -> None:
    # Madgwick yaw starts 0.3 rad away from the world of R_world_marker (no magnetometer)
    p_w = np.array([-4.0, 0.5, 0.0])
    R_wb = euler_to_rotmat(0.0, 0.0, 0.3)
    paper = make_estimator("FCF-MF")
    seed_attitude(paper, (0.0, 0.0, 0.0))
    off = paper.update_vision(observe(paper.config, R_wb, p_w, t=0.01))
    assert off is not None and abs(off.x_m - 0.5) > 0.5  # the yaw error moves the estimate
    aligned = make_estimator("FCF-MF", DartEstimatorConfig(yaw_align_tau_s=0.0))
    seed_attitude(aligned, (0.0, 0.0, 0.0))
    out = aligned.update_vision(observe(aligned.config, R_wb, p_w, t=0.01))
    assert out is not None and isinstance(aligned, MadgwickPositionEstimator)
    assert (out.x_m, out.y_m, out.z_m) == pytest.approx((0.5, 0.0, 4.0), abs=1e-9)
    assert aligned.yaw_offset_rad == pytest.approx(0.3)


def test_rejects_and_counts_bad_observations() -> None:
    est = make_estimator("FCF-MF")
    good = CameraMarkerObservation(0.0, np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 4.0]))
    assert est.update_vision(good) is None  # no IMU sample yet: no attitude
    assert est.no_attitude_observations == 1
    seed_attitude(est, (0.0, 0.0, 0.0), t0=1.0)
    bad = [
        CameraMarkerObservation(1.0, np.diag([1.0, -1.0, -1.0]), np.array([0.0, math.nan, 4.0])),
        CameraMarkerObservation(1.0, 2.0 * np.eye(3), np.array([0.0, 0.0, 4.0])),  # not a rotation
        CameraMarkerObservation(1.0, np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, -4.0])),
    ]
    for obs in bad:
        assert est.update_vision(obs) is None
    assert est.rejected_observations == 3
    # older than the attitude history (half a second by default)
    for k in range(3, 200):
        est.update_imu(1.0 + 0.005 * k, (0.0, 0.0, 0.0), (0.0, 0.0, -G))
    old = CameraMarkerObservation(1.0, np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 4.0]))
    assert est.update_vision(old) is None and est.stale_observations == 1
    assert est.update_vision(CameraMarkerObservation(1.9, np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 4.0])))
    assert est.accepted_observations == 1
    # the IMU stopped 0.3 s before this exposure (max_attitude_age_s = 0.2): attitude unknown
    late = CameraMarkerObservation(1.0 + 0.005 * 199 + 0.3, np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 4.0]))
    assert est.update_vision(late) is None and est.no_attitude_observations == 2


def test_factory() -> None:
    for name in ("fcf-cf", "FCF_MF", " scf-mf-2dof ", "SCF-MF-3DOF"):
        assert make_estimator(name).name == name.strip().upper().replace("_", "-")
    with pytest.raises(ValueError, match="unknown Dart estimator"):
        make_estimator("EKF")
    assert [ESTIMATORS[n].gimbal for n in ("FCF-CF", "FCF-MF")] == [GimbalKind.NONE] * 2


def test_corrected_sample_std_eq22() -> None:
    # (1, 2, 3, 4): mean 2.5, squares 2.25 + 0.25 + 0.25 + 2.25 = 5, 5 / (4 - 1) -> sqrt = 1.290994
    assert corrected_sample_std([1.0, 2.0, 3.0, 4.0]) == pytest.approx(1.2909944, abs=1e-7)
    data = list(np.random.default_rng(2).normal(0.0, 0.05, 50))
    assert corrected_sample_std(data) == pytest.approx(float(np.std(data, ddof=1)))
    assert math.isnan(corrected_sample_std([1.0]))


def test_task_rates_from_the_paper() -> None:
    r = DartTaskRates()
    assert (r.vision_hz, r.imu_hz, r.control_hz, r.command_hz, r.log_hz) == (30, 200, 22, 44, 20)


def test_fcf_cf_delayed_frames_use_the_filtered_attitude_at_exposure() -> None:
    # exact vision delayed by 60 ms (12 IMU samples) while the drone rocks at ~0.5 rad/s:
    # the estimate stays exact because the frame is compared with the attitude at its exposure
    cfg = DartEstimatorConfig(complementary=ComplementaryConfig(lam=0.9))
    est = FcfCfEstimator(cfg)
    p_w = np.array([-3.0, 0.4, -0.2])
    truth = np.array(cfg.R_world_marker).T @ p_w

    def rpy_at(t: float) -> tuple[float, float, float]:
        return (0.2 * math.sin(2.5 * t), 0.2 * math.cos(2.0 * t), 0.1 * math.sin(t))

    def body_rates(t: float, h: float = 1e-5) -> np.ndarray:
        R0, R1 = euler_to_rotmat(*rpy_at(t - h)), euler_to_rotmat(*rpy_at(t + h))
        W = R0.T @ (R1 - R0) / (2 * h)
        return np.array([W[2, 1], W[0, 2], W[1, 0]])

    pending: list[CameraMarkerObservation] = []
    errors = []
    for k in range(1, 800):
        t = k * 0.005
        est.update_imu(t, tuple(body_rates(t - 0.0025)), (0.0, 0.0, -G))
        if k % 7 == 0:
            pending.append(observe(cfg, euler_to_rotmat(*rpy_at(t)), p_w, t=t))
        if pending and pending[0].time_s <= t - 0.06 + 1e-9:
            out = est.update_vision(pending.pop(0))
            # the second frame was exposed before the first one was fused (which started the
            # filter): no attitude history reaches back to it, so it is rejected as stale
            assert out is not None or est.stale_observations == 1
            if out is not None and t > 1.0:
                errors.append(np.linalg.norm(np.array([out.x_m, out.y_m, out.z_m]) - truth))
    assert max(errors) < 0.01
    assert est.accepted_observations >= 110 and est.stale_observations == 1
