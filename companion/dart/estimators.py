"""The four Dart position estimators FCF-CF, FCF-MF, SCF-MF-2DOF, SCF-MF-3DOF (dart sec. 3.2.4).

Each turns a marker observation from the vision system (the marker pose in the camera frame,
as a PnP returns it: rotation R_cam_marker and translation Q_m = t_cam_marker, dart eq 1) plus an
attitude estimate into the position of the drone's centre of thrust relative to the marker.

Frames (docs/architecture.md): world W = local NED (the attitude filters' reference), body B =
FRD with its origin at the centre of thrust, camera C = OpenCV (x right, y down, z optical axis),
marker M = ArUco (x right, y up, z out of the marker plane). ``R_a_b`` maps b-coordinates into a.

Configured geometry: the camera mount R_body_cam and the lens position t_body_cam (the paper's
Q_off, "the distance between the camera and the center of thrust"; in camera axes
Q_off = R_body_cam^T t_body_cam), the marker orientation R_world_marker, and for the 3-DOF
gimbal the heading it holds. The output is the centre of thrust in marker coordinates,
p = (x_m, y_m, z_m): z_m is the distance out of the marker plane, so a drone hovering 4 m in
front of a wall marker has z_m = +4 whatever the camera's axes are.

The paper's equations give Q_hat = R Q_ct, the marker seen from the centre of thrust, rotated
into the marker-aligned frame; the drone in the marker frame is its negative, p = -Q_hat.

- FCF-CF (dart eqs 14-18): camera fixed to the body. Phi = the marker-camera relative attitude
  from vision, fused with the gyro by the complementary filter (eq 14); then eq 16/18
  p = -R(Phi_hat) (Q_m + Q_off) with R(Phi_hat) = R_marker_cam.
- FCF-MF (dart eq 16 with the Madgwick attitude, Fig. 9): camera fixed; the attitude comes from
  the Madgwick filter (eqs 8-13) and no vision attitude is needed:
  R(Phi_hat) = R_marker_world R_world_body(Phi_hat) R_body_cam.
- SCF-MF-2DOF (dart eqs 19-20): the gimbal levels the camera (roll, pitch), the camera yaws with
  the body: Q_hat = R_Z(psi_hat) Q_m + R_XYZ(Phi_hat) Q_off; in frames,
  p = -R_marker_world (Rz(psi_hat) R_body_cam Q_m + R_world_body(Phi_hat) t_body_cam).
- SCF-MF-3DOF (dart eq 21): the gimbal holds the camera's full attitude (a fixed heading), so
  Q_m is used without any estimated rotation: Q_hat = Q_m + R_XYZ(Phi_hat) Q_off, in frames
  p = -(R_marker_camS Q_m + R_marker_world R_world_body(Phi_hat) t_body_cam) with the constant
  R_marker_camS = R_marker_world Rz(psi_gimbal) R_body_cam.

dart eq 17 (R_XYZ) and eq 20 (R_Z) are the paper's own parametrisations of these rotations,
with the angles named after camera axes (phi about the optical axis z, theta about x, psi about
y). :func:`dart_r_xyz` and :func:`dart_r_z` reproduce them literally:
R_XYZ(phi, theta, psi) = (Rx(theta) Ry(psi) Rz(phi))^T and R_Z(psi) = Rz(psi)^T, i.e. passive
(frame) rotations. The estimators build the same relative rotations from the project's ZYX
convention (geometry.euler_to_rotmat) so every frame is explicit.

Ambiguity: an observation flagged ``ambiguous`` (the IPPE two-fold planar ambiguity left
unresolved by the detector) is gated in every estimator, FCF-CF included, and counted in
``ambiguous_observations``; it never reaches a filter.

Timing (docs/architecture.md: time is an input): observations carry the exposure time; the estimators keep a
short history of the attitude (IMU rate) and use the attitude at the exposure time. Yaw from
the Madgwick filter is not observable and drifts; ``yaw_offset_rad`` aligns it to the world of
R_world_marker and, when ``yaw_align_tau_s`` is set (not in the paper, off by default), the
offset follows the vision heading with that time constant (fixed camera and 2-DOF gimbal only).
"""

from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import Field, field_validator

from companion.config import _f
from companion.estimation.complementary import ComplementaryFilter
from companion.estimation.madgwick import MadgwickFilter
from companion.geometry import (
    euler_to_rotmat,
    quat_to_rotmat,
    rot_z,
    rotmat_to_euler,
    wrap_angle,
)
from companion.param_kinds import DartEstimatorTable, _s

logger = logging.getLogger(__name__)

Matrix3 = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]
FloatArray = NDArray[np.float64]


# ---------------------------------------------------------------------------- paper matrices
def dart_r_xyz(phi: float, theta: float, psi: float) -> FloatArray:
    """dart eq 17, literally: R_XYZ(Phi) for Phi = (phi, theta, psi). Equals
    (Rx(theta) Ry(psi) Rz(phi))^T (phi about z, theta about x, psi about y)."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return np.array(
        [
            [cf * cp, cf * sp * st + sf * ct, -cf * sp * ct + sf * st],
            [-sf * cp, -sf * sp * st + cf * ct, sf * sp * ct + cf * st],
            [sp, -cp * st, cp * ct],
        ]
    )


def dart_r_z(psi: float) -> FloatArray:
    """dart eq 20, literally: R_Z(psi) = Rz(psi)^T."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


# ------------------------------------------------------------------------ geometry helpers
def _as_matrix3(R: ArrayLike) -> Matrix3:
    m = np.asarray(R, dtype=float)
    if m.shape != (3, 3):
        raise ValueError(f"rotation must be 3x3, got {m.shape}")
    if not np.allclose(m @ m.T, np.eye(3), atol=1e-6) or np.linalg.det(m) < 0.0:
        raise ValueError("not a rotation matrix (orthonormal, det +1)")
    return tuple(tuple(float(v) for v in row) for row in m)  # type: ignore[return-value]


# OpenCV camera axes in the FRD body when the camera looks forward: cam z -> body x,
# cam x -> body y, cam y -> body z.
_R_FRD_CV = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def camera_mount(pitch_rad: float = 0.0, yaw_rad: float = 0.0, roll_rad: float = 0.0) -> Matrix3:
    """R_body_cam of a camera rotated (ZYX) from the forward-looking mount.

    ``camera_mount()`` looks forward (the paper's Raspicam); ``camera_mount(-pi/2)`` looks down.
    """
    return _as_matrix3(euler_to_rotmat(roll_rad, pitch_rad, yaw_rad) @ _R_FRD_CV)


def wall_marker(facing_yaw_rad: float = 0.0) -> Matrix3:
    """R_world_marker of a vertical marker seen by a drone heading ``facing_yaw_rad``:
    marker x to the drone's right, y up, z towards the drone (the paper's set-up)."""
    base = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    return _as_matrix3(rot_z(facing_yaw_rad) @ base)


def ground_marker(yaw_rad: float = 0.0) -> Matrix3:
    """R_world_marker of a marker lying flat, z up: marker x towards ``yaw_rad`` (NED heading),
    y to its left (seen from above)."""
    base = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    return _as_matrix3(rot_z(yaw_rad) @ base)


# ------------------------------------------------------------------------------ messages
class MarkerPoseLike(Protocol):
    """What the estimators read from a marker observation (vision.MarkerObservation or
    :class:`CameraMarkerObservation`)."""

    @property
    def time_s(self) -> float: ...
    @property
    def R_cam_marker(self) -> ArrayLike: ...
    @property
    def t_cam_marker_m(self) -> ArrayLike: ...


class _PoseLike(Protocol):
    @property
    def R(self) -> ArrayLike: ...
    @property
    def t(self) -> ArrayLike: ...


class DetectionLike(Protocol):
    """What :meth:`CameraMarkerObservation.from_detection` reads (vision.MarkerObservation)."""

    @property
    def time_s(self) -> float: ...
    @property
    def T_camera_pad(self) -> _PoseLike: ...
    @property
    def ambiguous(self) -> bool: ...


@dataclass(frozen=True, slots=True, eq=False)
class CameraMarkerObservation:
    """A marker pose in the camera frame from a PnP, timestamped at exposure (dart eqs 1, 5)."""

    time_s: float
    R_cam_marker: FloatArray
    t_cam_marker_m: FloatArray  # Q_m, dart eq 1
    marker_id: int = 0
    # IPPE two-fold ambiguity unresolved (vision.MarkerObservation.ambiguous): never fused
    ambiguous: bool = False

    @classmethod
    def from_detection(cls, detection: DetectionLike) -> CameraMarkerObservation:
        """From a vision.MarkerObservation (exposure time, T_camera_pad, ambiguity flag)."""
        T = detection.T_camera_pad
        return cls(
            float(detection.time_s),
            np.asarray(T.R, dtype=float),
            np.asarray(T.t, dtype=float),
            ambiguous=bool(detection.ambiguous),
        )


@dataclass(frozen=True, slots=True)
class DartPositionEstimate:
    """Centre of thrust in the marker frame (metres) and the body attitude that was used.

    roll/pitch are the body's ZYX angles in world NED; ``yaw_rad`` is the body heading relative
    to ``reference_yaw_rad`` (0 = facing the marker in the paper's set-up), the C_psi input.
    """

    time_s: float
    x_m: float
    y_m: float
    z_m: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    method: str
    marker_id: int = 0


class GimbalKind(Enum):
    NONE = "none"  # camera fixed to the body (FCF-*)
    TWO_DOF = "2dof"  # roll and pitch stabilised (SCF-MF-2DOF)
    THREE_DOF = "3dof"  # roll, pitch and yaw stabilised (SCF-MF-3DOF)


@dataclass(frozen=True, slots=True)
class DartTaskRates:
    """Task rates of the Dart software (dart sec. 4)."""

    vision_hz: float = 30.0  # aperiodic, ~30 FPS at 660x660
    imu_hz: float = 200.0  # IMU thread: Madgwick + position estimation
    control_hz: float = 22.0  # PID thread, half the PPM bandwidth
    command_hz: float = 44.0  # mixer communication, the PPM bandwidth
    log_hz: float = 20.0  # mission log, lowest priority


def _unit(unit: str, description: str, factory: Callable[[], Any]) -> Any:
    """A geometry field with its unit and description; its default from ``factory``."""
    return Field(default_factory=factory, description=description, json_schema_extra={"unit": unit})


class DartEstimatorConfig(DartEstimatorTable):
    """What the four estimators take: the filter settings of ``[estimator]`` (declared once in
    companion.param_kinds.DartEstimatorTable, the Madgwick and complementary filters' tables in
    it) and the geometry, which a Dart file gives as ``[runtime]`` (lens_offset_m,
    marker_heading_deg) or ``[sim]`` (lens_offset_m): :meth:`with_geometry`."""

    R_body_cam: Matrix3 = _unit("-", "camera mount rotation, body FRD from camera (forward camera)", camera_mount)
    t_body_cam_m: tuple[float, float, float] = _f(
        (0.08, 0.0, 0.03), "m", "lens from the centre of thrust, body FRD (the paper's Q_off)"
    )
    R_world_marker: Matrix3 = _unit("-", "marker orientation in world NED (wall marker, drone heading N)", wall_marker)
    reference_yaw_rad: float = _s(0.0, "rad", "body heading reported as yaw 0 (facing the marker)")
    gimbal_yaw_rad: float = _s(0.0, "rad", "heading (world) the 3-DOF gimbal holds")

    @field_validator("R_body_cam", "R_world_marker", mode="before")
    @classmethod
    def _rotation(cls, v: Any) -> Matrix3:
        return _as_matrix3(v)

    @classmethod
    def with_geometry(cls, table: DartEstimatorTable, **geometry: Any) -> DartEstimatorConfig:
        """``table``'s settings (``[estimator]`` of a file) with the geometry given here."""
        return cls(**dict(table), **geometry)


def corrected_sample_std(errors: Sequence[float]) -> float:
    """dart eq 22: sqrt(sum (e - mean)^2 / (N - 1)); NaN for fewer than two samples."""
    n = len(errors)
    if n < 2:
        return float("nan")
    mean = sum(errors) / n
    return math.sqrt(sum((e - mean) ** 2 for e in errors) / (n - 1))


# ----------------------------------------------------------------------------- estimators
_I3 = np.eye(3)


def _nearest(history: deque[tuple[float, ...]], t: float) -> tuple[float, ...] | None:
    """The history entry closest in time to t (entries in increasing time)."""
    if not history:
        return None
    after: tuple[float, ...] | None = None
    for entry in reversed(history):
        if entry[0] <= t:
            if after is not None and after[0] - t < t - entry[0]:
                return after
            return entry
        after = entry
    return after  # t before the whole history: the oldest entry


def _yaw_of(R: FloatArray) -> float:
    return math.atan2(float(R[1, 0]), float(R[0, 0]))


class DartEstimator(ABC):
    """Common part: configuration, observation checks, counters, attitude history.

    ``update_imu`` at the IMU rate, ``update_vision`` at the camera rate; the latter returns a
    :class:`DartPositionEstimate` or None when the observation was rejected (counted).
    """

    name = "base"
    gimbal = GimbalKind.NONE

    def __init__(self, config: DartEstimatorConfig | None = None) -> None:
        self.config = config or DartEstimatorConfig()
        c = self.config
        self._R_bc = np.array(c.R_body_cam, dtype=float)
        self._t_bc = np.array(c.t_body_cam_m, dtype=float)
        self._q_off = self._R_bc.T @ self._t_bc  # Q_off in camera axes (dart eq 16)
        self._R_wm = np.array(c.R_world_marker, dtype=float)
        self._R_mw = self._R_wm.T
        self._history: deque[tuple[float, ...]] = deque()
        self.last: DartPositionEstimate | None = None
        self.accepted_observations = 0
        self.rejected_observations = 0  # malformed (NaN, not a rotation, marker behind camera)
        self.stale_observations = 0  # older than the attitude history
        self.no_attitude_observations = 0  # no (recent) IMU sample
        self.ambiguous_observations = 0  # IPPE mirror pair unresolved: gated, not fused

    # history ---------------------------------------------------------------
    @property
    def attitude_history(self) -> tuple[tuple[float, ...], ...]:
        """The attitude history delayed frames are fused against, oldest first (a copy): per IMU
        sample its time in s, then the estimator's attitude (FCF-CF: roll, pitch, yaw in rad;
        Madgwick: its quaternion)."""
        return tuple(self._history)

    def _record(self, entry: tuple[float, ...]) -> None:
        h = self._history
        h.append(entry)
        horizon = entry[0] - self.config.history_s
        while h[0][0] < horizon:
            h.popleft()

    def _check(self, obs: MarkerPoseLike) -> tuple[float, FloatArray, FloatArray] | None:
        if bool(getattr(obs, "ambiguous", False)):
            # the planar pose's mirror pair was not resolved (vision.detector.resolve_ambiguity):
            # its attitude may be the wrong one of the two, so no estimator fuses it (FCF-CF would
            # take the attitude, the Madgwick-based ones a position from the same unsure solve)
            self.ambiguous_observations += 1
            return None
        try:
            t = float(obs.time_s)
            R = np.asarray(obs.R_cam_marker, dtype=float).reshape(3, 3)
            q = np.asarray(obs.t_cam_marker_m, dtype=float).reshape(3)
        except (TypeError, ValueError):
            self.rejected_observations += 1
            return None
        # (the finiteness test on Python floats: the array form's five numpy calls cost ~3 us)
        if not (math.isfinite(t) and all(map(math.isfinite, R.ravel().tolist() + q.tolist()))):
            self.rejected_observations += 1
            return None
        if float(np.abs(R.dot(R.T) - _I3).max()) > self.config.max_rotation_error or not (q[2] > 0.0):
            self.rejected_observations += 1
            return None
        if self._history and t < self._history[0][0] - 0.5 / self.config.madgwick.nominal_rate_hz:
            self.stale_observations += 1
            return None
        return t, R, q

    def _finish(self, t: float, p: FloatArray, R_wb: FloatArray, marker_id: int) -> DartPositionEstimate:
        roll, pitch, yaw = rotmat_to_euler(R_wb)
        est = DartPositionEstimate(
            time_s=t,
            x_m=float(p[0]),
            y_m=float(p[1]),
            z_m=float(p[2]),
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=wrap_angle(yaw - self.config.reference_yaw_rad),
            method=self.name,
            marker_id=marker_id,
        )
        self.accepted_observations += 1
        self.last = est
        return est

    @abstractmethod
    def update_imu(self, time_s: float, gyro_rad_s: Sequence[float], accel_m_s2: Sequence[float]) -> bool:
        """Feed one IMU sample (body rates rad/s, specific force m/s^2, FRD) at ``time_s``."""

    @abstractmethod
    def update_vision(self, obs: MarkerPoseLike) -> DartPositionEstimate | None:
        """Fuse one marker observation; None when it was rejected (counted)."""


class FcfCfEstimator(DartEstimator):
    """FCF-CF: fixed camera, complementary filter of vision attitude and gyro (dart eqs 14-18).

    The filtered angle vector Phi is the ZYX Euler triple of R_marker_cam. The gyro rate of the
    camera, omega_C = R_cam_body omega_B, enters eq 14 as Euler rates J_r(Phi) omega_C (the
    paper's "T Omega" is the small-angle case J_r = I). The accelerometer is not used (Fig. 8).
    A delayed vision frame is compared with the filtered attitude at its exposure time; the
    correction shifts the history after it, so later frames see a consistent trajectory.
    """

    name = "FCF-CF"
    gimbal = GimbalKind.NONE

    def __init__(self, config: DartEstimatorConfig | None = None) -> None:
        super().__init__(config)
        self.cf = ComplementaryFilter(self.config.complementary)
        self._R_cb_f = tuple(float(v) for v in self._R_bc.T.reshape(9))
        self.rejected_imu = 0

    def update_imu(self, time_s: float, gyro_rad_s: Sequence[float], accel_m_s2: Sequence[float] = ()) -> bool:
        bx, by, bz = gyro_rad_s
        r = self._R_cb_f
        wx = r[0] * bx + r[1] * by + r[2] * bz
        wy = r[3] * bx + r[4] * by + r[5] * bz
        wz = r[6] * bx + r[7] * by + r[8] * bz
        phi, theta, _ = self.cf.angles
        sf, cf = math.sin(phi), math.cos(phi)
        ct = math.cos(theta)
        if abs(ct) < 1e-3:  # Euler singularity (camera x along the marker normal: not seen)
            ct = math.copysign(1e-3, ct)
        tt = math.sin(theta) / ct
        rates = (
            wx + sf * tt * wy + cf * tt * wz,
            cf * wy - sf * wz,
            (sf * wy + cf * wz) / ct,
        )
        if not self.cf.predict(time_s, rates):
            self.rejected_imu += 1
            return False
        if self.cf.initialised:
            a = self.cf.angles
            self._record((time_s, a[0], a[1], a[2]))
        return True

    def _shift_history(self, t: float, jump: tuple[float, ...]) -> None:
        """Add ``jump`` to the filtered angles of every history entry at or after ``t``. The
        history is in time order, so only its tail (the frame's delay, a few entries) is visited,
        from the newest back, and replaced in place."""
        j0, j1, j2 = jump
        pi, two_pi = math.pi, 2.0 * math.pi
        h = self._history
        i = len(h) - 1
        while i >= 0:
            e = h[i]
            if e[0] < t:
                break
            # wrap_angle(e[k] + j), inlined (the same arithmetic: exact for angles in range)
            a0, a1, a2 = e[1] + j0, e[2] + j1, e[3] + j2
            if not -pi <= a0 < pi:
                a0 = (a0 + pi) % two_pi - pi
            if not -pi <= a1 < pi:
                a1 = (a1 + pi) % two_pi - pi
            if not -pi <= a2 < pi:
                a2 = (a2 + pi) % two_pi - pi
            h[i] = (e[0], a0, a1, a2)
            i -= 1

    def update_vision(self, obs: MarkerPoseLike) -> DartPositionEstimate | None:
        checked = self._check(obs)
        if checked is None:
            return None
        t, R_cm, q_m = checked
        measured: tuple[float, ...] = rotmat_to_euler(R_cm.T)  # Phi: attitude of R_marker_cam (dart eq 5)
        cf = self.cf
        if not cf.initialised:  # first frame: the filter starts at the measurement
            cf.reset(measured, time_s=cf.time_s)
            phi_obs = measured
        else:
            now = cf.angles
            entry = _nearest(self._history, t)
            past = now if entry is None else (entry[1], entry[2], entry[3])
            # (per-component tuples written out: a generator per tuple costs ~1 us)
            d0, d1, d2 = wrap_angle(now[0] - past[0]), wrap_angle(now[1] - past[1]), wrap_angle(now[2] - past[2])
            # the measurement carried forward to "now" by the gyro increment since exposure
            cf.correct(
                (wrap_angle(measured[0] + d0), wrap_angle(measured[1] + d1), wrap_angle(measured[2] + d2))
            )  # eq 14
            new = cf.angles
            jump = (wrap_angle(new[0] - now[0]), wrap_angle(new[1] - now[1]), wrap_angle(new[2] - now[2]))
            # the correction holds from the exposure on: shift the later history with it
            self._shift_history(t, jump)
            phi_obs = (wrap_angle(new[0] - d0), wrap_angle(new[1] - d1), wrap_angle(new[2] - d2))
        R_mc = euler_to_rotmat(*phi_obs)  # R(Phi_hat) = R_marker_cam (dart eq 17's role)
        p = -(R_mc @ (q_m + self._q_off))  # dart eqs 16, 18: Q_hat = R(Phi_hat)(Q_m + Q_off)
        R_wb = self._R_wm @ R_mc @ self._R_bc.T
        return self._finish(t, p, R_wb, int(getattr(obs, "marker_id", 0)))


class MadgwickPositionEstimator(DartEstimator):
    """Common part of the three Madgwick-based estimators (dart Figs. 9-11)."""

    def __init__(self, config: DartEstimatorConfig | None = None, madgwick: MadgwickFilter | None = None) -> None:
        super().__init__(config)
        self.madgwick = madgwick or MadgwickFilter(self.config.madgwick)
        self.yaw_offset_rad = self.config.yaw_offset_rad
        self._align_t: float | None = None

    def update_imu(self, time_s: float, gyro_rad_s: Sequence[float], accel_m_s2: Sequence[float]) -> bool:
        m = self.madgwick
        if not m.update(time_s, gyro_rad_s, accel_m_s2):
            return False
        self._record((time_s, *m.quaternion))
        return True

    def _attitude_at(self, t: float) -> FloatArray | None:
        """R_world_body at time t: Madgwick (history) with the yaw offset applied."""
        if not self._history or t - self._history[-1][0] > self.config.max_attitude_age_s:
            return None  # no IMU yet, or the IMU stopped: the attitude is unknown
        entry = _nearest(self._history, t)
        if entry is None:
            return None
        R = quat_to_rotmat(entry[1:5])
        if self.yaw_offset_rad != 0.0:
            R = rot_z(self.yaw_offset_rad) @ R
        return R

    def _align_yaw(self, t: float, R_cm: FloatArray, R_wb: FloatArray) -> FloatArray:
        """Optional: pull the yaw offset towards the heading the vision implies."""
        tau = self.config.yaw_align_tau_s
        if tau is None or self.gimbal is GimbalKind.THREE_DOF:
            return R_wb
        # camera heading from vision, body heading = camera heading less the mount
        # (fixed camera: R_wb = R_wc R_bc^T; 2-DOF gimbal: Rz(psi) = R_wc R_bc^T)
        R_wb_vision = self._R_wm @ R_cm.T @ self._R_bc.T
        innov = wrap_angle(_yaw_of(R_wb_vision) - _yaw_of(R_wb))
        if self._align_t is None or tau == 0.0:
            k = 1.0
        else:
            dt = max(0.0, t - self._align_t)
            k = dt / (tau + dt)
        self._align_t = t
        self.yaw_offset_rad = wrap_angle(self.yaw_offset_rad + k * innov)
        return rot_z(k * innov) @ R_wb

    def update_vision(self, obs: MarkerPoseLike) -> DartPositionEstimate | None:
        checked = self._check(obs)
        if checked is None:
            return None
        t, R_cm, q_m = checked
        R_wb = self._attitude_at(t)
        if R_wb is None:
            self.no_attitude_observations += 1
            return None
        R_wb = self._align_yaw(t, R_cm, R_wb)
        p = self._position(q_m, R_wb)
        return self._finish(t, p, R_wb, int(getattr(obs, "marker_id", 0)))

    @abstractmethod
    def _position(self, q_m: FloatArray, R_wb: FloatArray) -> FloatArray:
        """The centre of thrust in the marker frame from Q_m and R_world_body."""


class FcfMfEstimator(MadgwickPositionEstimator):
    """FCF-MF: fixed camera, attitude from the Madgwick filter (dart eq 16, Fig. 9)."""

    name = "FCF-MF"
    gimbal = GimbalKind.NONE

    def _position(self, q_m: FloatArray, R_wb: FloatArray) -> FloatArray:
        R_mc = self._R_mw @ R_wb @ self._R_bc  # R(Phi_hat): lens frame onto marker frame
        return -(R_mc @ (q_m + self._q_off))  # dart eq 16: Q_hat = R(Phi_hat)(Q_m + Q_off)


class ScfMf2DofEstimator(MadgwickPositionEstimator):
    """SCF-MF-2DOF: roll/pitch-stabilised camera, Madgwick attitude (dart eqs 19-20, Fig. 10)."""

    name = "SCF-MF-2DOF"
    gimbal = GimbalKind.TWO_DOF

    def _position(self, q_m: FloatArray, R_wb: FloatArray) -> FloatArray:
        psi = _yaw_of(R_wb)
        # dart eq 19: Q_hat = R_Z(psi_hat) Q_m + R_XYZ(Phi_hat) Q_off; the marker coordinates
        # turn with the yaw only (eq 20), the lever arm with the whole attitude
        q_world = rot_z(psi) @ (self._R_bc @ q_m) + R_wb @ self._t_bc
        return -(self._R_mw @ q_world)


class ScfMf3DofEstimator(MadgwickPositionEstimator):
    """SCF-MF-3DOF: fully stabilised camera, Madgwick attitude (dart eq 21, Fig. 11)."""

    name = "SCF-MF-3DOF"
    gimbal = GimbalKind.THREE_DOF

    def __init__(self, config: DartEstimatorConfig | None = None, madgwick: MadgwickFilter | None = None) -> None:
        super().__init__(config, madgwick)
        # constant: the gimbal holds the camera at this attitude
        self._R_m_cams = self._R_mw @ rot_z(self.config.gimbal_yaw_rad) @ self._R_bc

    def _position(self, q_m: FloatArray, R_wb: FloatArray) -> FloatArray:
        # dart eq 21: Q_hat = Q_m + R_XYZ(Phi_hat) Q_off (Q_m needs no estimated rotation)
        return -(self._R_m_cams @ q_m + self._R_mw @ (R_wb @ self._t_bc))


ESTIMATORS: dict[str, type[DartEstimator]] = {
    cls.name: cls for cls in (FcfCfEstimator, FcfMfEstimator, ScfMf2DofEstimator, ScfMf3DofEstimator)
}


def make_estimator(
    name: str,
    config: DartEstimatorConfig | None = None,
    madgwick: MadgwickFilter | None = None,
) -> DartEstimator:
    """One of "FCF-CF", "FCF-MF", "SCF-MF-2DOF", "SCF-MF-3DOF" (case and '_' / '-' ignored).

    ``madgwick`` lets the Madgwick-based estimators use a given filter; the estimator then
    updates it from ``update_imu`` (do not update it elsewhere too).
    """
    key = name.strip().upper().replace("_", "-")
    cls = ESTIMATORS.get(key)
    if cls is None:
        raise ValueError(f"unknown Dart estimator {name!r}; choose one of {sorted(ESTIMATORS)}")
    if cls is FcfCfEstimator:
        if madgwick is not None:
            raise ValueError("FCF-CF uses the complementary filter, not the Madgwick filter")
        return FcfCfEstimator(config)
    return cls(config, madgwick)  # type: ignore[call-arg]


__all__ = [
    "ESTIMATORS",
    "CameraMarkerObservation",
    "DartEstimator",
    "DartEstimatorConfig",
    "DartPositionEstimate",
    "DartTaskRates",
    "FcfCfEstimator",
    "FcfMfEstimator",
    "GimbalKind",
    "MadgwickPositionEstimator",
    "MarkerPoseLike",
    "ScfMf2DofEstimator",
    "ScfMf3DofEstimator",
    "camera_mount",
    "corrected_sample_std",
    "dart_r_xyz",
    "dart_r_z",
    "ground_marker",
    "make_estimator",
    "wall_marker",
]
