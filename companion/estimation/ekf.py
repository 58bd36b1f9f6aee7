"""The 12-state EKF of the delivery paper (section 4.2.3, eqs 5-15) fusing the autopilot pose
(GPS, "DJI-SDK pose"), ArUco PnP and UWB fixes.

State (delivery eq 10), world frame local NED, ZYX Euler angles:

    x = [p (3, NED m), r = (roll, pitch, yaw) (3, rad), b_p GPS bias (3, m), b_w gyro bias (3, rad/s)]

Input u = [world velocity (3, m/s NED), body rates (3, rad/s FRD)].

* prediction (eqs 5, 6, 11): x <- x + [u_v; J_r(u_w - b_w); 0; 0] dt,
  P <- F P F^T + G Q_u G^T + Q_f, with F = df/dx and G = df/du (analytic).
* correction (eqs 7, 9) with the Joseph form P <- (I-KH) P (I-KH)^T + K R K^T instead of eq 8:
  eq 8 is only correct for the optimal gain and in floating point loses symmetry and positive
  definiteness (its error is first order in the gain error); the Joseph form is second order and
  symmetric PSD by construction. Every step keeps a symmetric P exactly symmetric (see Speed)
  and the diagonal is floored after every step.
* measurement models: h_SDK (eq 12) p + xi b_p and r; h_ArUco (eqs 13-14) the marker pose in the
  camera, (H_c^d)^-1 (H_d^w)^-1 H_a^w, as position and ZYX Euler angles; h_UWB (eq 15) p.
  Angle residuals are wrapped to [-pi, pi). All Jacobians are analytic (tested against central
  finite differences in tests/estimation/test_ekf_jacobians.py).

Implementation choice: hand-written numpy rather than ``filterpy.kalman.ExtendedKalmanFilter``.
The filter needs angle-wrapped residuals, a Joseph update with a per-call R, chi-square gating
before the state is touched and cheap snapshots for the delayed-measurement replay; filterpy's
EKF would need all of that bolted on through callbacks, and costs more per predict.

Speed: the steps use the model's structure (F is the identity but for the attitude rows, G is
zero below row 6 and block diagonal above, ArUco sees only p and r, UWB only p), and numpy costs
~0.5-1 us a call on these sizes, so the aim is few calls:

* eq 6 changes only rows and columns 3-5 of P: F3 P (rows 3-5 of F) gives the rows, the columns
  are their transpose (P symmetric), the 3x3 block F3 P F3^T is symmetrised and G Q_u G^T added
  on floats (G Q_u G^T is dt^2 Q_v on p's diagonal and G_r Q_w G_r^T, G_r = J_r dt, on the
  attitude block), Q_f with dt^2 Q_v is one cached diagonal. The result is exactly symmetric.
* the correction runs on the non-zero columns of H; S = H P H^T + R is factored once (Cholesky,
  LAPACK potrf/potrs) instead of inverted and not re-symmetrised (potrf reads one triangle); the
  Joseph form is regrouped as P + N + N^T, N = (K S / 2 - P H^T) K^T (:func:`joseph_covariance`:
  still exact for any K, one dgemm for K S / 2 - P H^T), exactly symmetric too.
* so P is never re-symmetrised as a 12x12; ``P0`` and the xi switch's T P T^T are symmetrised
  once.
* the small work is done on Python floats: h_ArUco's 3x3 products are written out (summed in the
  order numpy's matmul sums them) and its Jacobian gathered into one flat list, the state stays
  a list of floats through a prediction's sub-steps and angle wrap and through eq 7's wrap; the
  12x12 products stay BLAS calls (``ndarray.dot``: less dispatch than ``@``).

:mod:`companion.estimation.ekf_reference` keeps the dense form (which re-symmetrises P and S
after every step); tests/estimation/test_ekf_sparse.py holds the two equal to ~1e-9 and
``companion bench ekf`` times both in one run.

Beyond the paper: chi-square (Mahalanobis) gating with per-sensor counters; measurement noise
sigma = sigma0 + gain * height above the pad (per sensor); the 30 m ArUco height gate (delivery
5.1); NaN/inf inputs and measurements rejected and counted; and a principled xi switch: while
xi = 0 the GPS bias is unobservable and keeps its prior (zero mean, uncorrelated with p), so the
position state really tracks the GPS position p + b_p. When the first pad-local measurement
(ArUco or UWB) is accepted, the state is re-expressed as p <- p - b_p (P <- T P T^T), after which
h_SDK = p + b_p (xi = 1) predicts exactly what it did before the switch and the local sensor sees
the GPS-bias uncertainty in its innovation covariance (so a large GPS offset is not gated out).
Also: without an initial state the first SDK pose initialises p and r (pad-local data before
that is refused: linearising eq 13 at a far-off state is meaningless), and after
``gate_reset_after_rejections`` consecutive gate rejections of one sensor the covariance it
disputes is re-inflated, so the filter cannot lock itself out of a sensor for good.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from enum import Enum
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg.blas import dgemm as _gemm
from scipy.linalg.lapack import dpotrf as _potrf
from scipy.linalg.lapack import dpotrs as _potrs
from scipy.special import gammaincinv

from companion.config import EkfConfig  # the schema of [landing.ekf], declared once there
from companion.estimation.types import StateEstimate
from companion.geometry import Transform, euler_rates_matrix, euler_to_rotmat

N_STATES = 12
P_IDX = slice(0, 3)
R_IDX = slice(3, 6)
BP_IDX = slice(6, 9)
BW_IDX = slice(9, 12)

_TWO_PI = 2.0 * math.pi


def chi2_ppf(p: float, dof: int) -> float:
    """The chi-square quantile of probability ``p`` with ``dof`` degrees of freedom (the innovation
    gate): 2 P^-1(dof / 2, p), P the regularised lower incomplete gamma function, which is what
    ``scipy.stats.chi2.ppf`` evaluates; called directly, the ~0.6 s import of ``scipy.stats`` stays
    out of every process that builds a filter (tests/estimation: equal to chi2.ppf)."""
    return float(2.0 * gammaincinv(dof / 2.0, p))


class EkfSensor(Enum):
    """The sensors the EKF fuses; the value names the sensor in the counters (``"sdk.accepted"``)."""

    SDK = "sdk"  # the autopilot's (GPS) pose, delivery eq 12
    ARUCO = "aruco"  # the pad's marker pose in the camera, eqs 13-14
    UWB = "uwb"  # a UWB position fix, eq 15


SENSORS = tuple(EkfSensor)


class UpdateOutcome(Enum):
    ACCEPTED = "accepted"
    REJECTED_NONFINITE = "rejected_nonfinite"
    REJECTED_GATE = "rejected_gate"
    REJECTED_HEIGHT = "rejected_height"
    REJECTED_NUMERICAL = "rejected_numerical"
    REJECTED_TOO_OLD = "rejected_too_old"
    REJECTED_UNINITIALIZED = "rejected_uninitialized"


class PositionFix(Protocol):
    """What the EKF needs from a UWB fix (``companion.uwb.UwbFix`` satisfies it)."""

    @property
    def time_s(self) -> float: ...
    @property
    def x_m(self) -> float: ...
    @property
    def y_m(self) -> float: ...
    @property
    def z_m(self) -> float: ...
    @property
    def pdop(self) -> float: ...


# ----------------------------------------------------------------------------------------------
# pure model functions (module level so the tests can check them against finite differences)


def wrap_angles(a: np.ndarray) -> np.ndarray:
    """Element-wise wrap to [-pi, pi)."""
    return (a + math.pi) % _TWO_PI - math.pi


def propagate(x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """f(x, u, dt) of delivery eq 11 (angles not wrapped here)."""
    out = x.copy()
    Jr = euler_rates_matrix(x[3], x[4])
    out[0:3] += u[0:3] * dt
    out[3:6] += (Jr @ (u[3:6] - x[9:12])) * dt
    return out


def _dJr_w(roll: float, pitch: float, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d(J_r w)/d roll and d(J_r w)/d pitch (J_r of delivery eq 11, ZYX)."""
    sr, cr = math.sin(roll), math.cos(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    tp = sp / cp
    w2, w3 = float(w[1]), float(w[2])
    a = cr * w2 - sr * w3  # d/droll of (sr w2 + cr w3)
    b = sr * w2 + cr * w3
    d_roll = np.array([tp * a, -sr * w2 - cr * w3, a / cp])
    d_pitch = np.array([b / (cp * cp), 0.0, b * sp / (cp * cp)])
    return d_roll, d_pitch


def propagation_jacobians(x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """F = df/dx (12x12) and G = df/du (12x6) of delivery eq 11 (used in eq 6)."""
    Jr = euler_rates_matrix(x[3], x[4])
    w = u[3:6] - x[9:12]
    d_roll, d_pitch = _dJr_w(x[3], x[4], w)
    F = np.eye(N_STATES)
    F[3:6, 3] += d_roll * dt
    F[3:6, 4] += d_pitch * dt
    F[3:6, 9:12] = -Jr * dt
    G = np.zeros((N_STATES, 6))
    G[0, 0] = G[1, 1] = G[2, 2] = dt
    G[3:6, 3:6] = Jr * dt
    return F, G


def propagation_blocks(x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """f(x, u, dt) of delivery eq 11 with the non-zero blocks of its Jacobians (eq 6): rows 3-5
    of F (its other rows are rows of I) and rows 0-5 of G (zero below). The same values as
    :func:`propagate` and :func:`propagation_jacobians` (up to rounding), in scalar arithmetic
    (numpy's per-call overhead dominates at this size)."""
    xl = x.tolist()
    F3, gr = _propagation_step(xl, u.tolist(), dt)
    g01, g02, g11, g12, g21, g22 = gr
    G6 = np.array(
        [
            [dt, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, dt, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, dt, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, dt, g01, g02],
            [0.0, 0.0, 0.0, 0.0, g11, g12],
            [0.0, 0.0, 0.0, 0.0, g21, g22],
        ]
    )
    return np.array(xl), F3, G6


def _propagation_step(xl: list[float], ul: list[float], dt: float) -> tuple[np.ndarray, tuple[float, ...]]:
    """:func:`propagation_blocks` on Python lists: ``xl`` becomes f(x, u, dt) in place (eq 11);
    returned are F3 (rows 3-5 of F) and the entries of J_r dt that are not 0 or dt (G's rate block,
    rows 3-5: [dt, g01, g02], [0, g11, g12], [0, g21, g22]), as floats: eq 6 needs G only in the
    3x3 noise block, which :func:`_covariance_step` sums on floats."""
    roll, pitch = xl[3], xl[4]
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    tp = math.tan(pitch)
    # J_r of eq 11 (row 0 = [1, j01, j02], row 1 = [0, j11, j12], row 2 = [0, j21, j22])
    j01, j02 = sr * tp, cr * tp
    j11, j12 = cr, -sr
    j21, j22 = sr / cp, cr / cp
    w1, w2, w3 = ul[3] - xl[9], ul[4] - xl[10], ul[5] - xl[11]  # omega - b_w
    xl[0] += ul[0] * dt  # p <- p + u_v dt
    xl[1] += ul[1] * dt
    xl[2] += ul[2] * dt
    xl[3] += (w1 + j01 * w2 + j02 * w3) * dt  # r <- r + J_r (omega - b_w) dt
    xl[4] += (j11 * w2 + j12 * w3) * dt
    xl[5] += (j21 * w2 + j22 * w3) * dt
    # d(J_r w)/d roll and d(J_r w)/d pitch (as _dJr_w)
    t = sp / cp
    a = cr * w2 - sr * w3
    b = sr * w2 + cr * w3
    cp2 = cp * cp
    F3 = np.array(
        [
            [0.0, 0.0, 0.0, 1.0 + t * a * dt, b / cp2 * dt, 0.0, 0.0, 0.0, 0.0, -dt, -j01 * dt, -j02 * dt],
            [0.0, 0.0, 0.0, (-sr * w2 - cr * w3) * dt, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -j11 * dt, -j12 * dt],
            [0.0, 0.0, 0.0, a / cp * dt, b * sp / cp2 * dt, 1.0, 0.0, 0.0, 0.0, 0.0, -j21 * dt, -j22 * dt],
        ]
    )
    return F3, (j01 * dt, j02 * dt, j11 * dt, j12 * dt, j21 * dt, j22 * dt)


def propagate_covariance(P: np.ndarray, F3: np.ndarray, G6: np.ndarray, qu: np.ndarray, Qf: np.ndarray) -> np.ndarray:
    """Delivery eq 6, P <- F P F^T + G Q_u G^T + Q_f, on the structure of eq 11: ``F3`` = rows 3-5
    of F (the others are rows of I), ``G6`` = rows 0-5 of G (zero below; dt I over the velocity
    inputs, J_r dt over the rates, zero between), ``qu`` = the diagonal of Q_u and ``Qf`` the
    diagonal of Q_f (both diagonal by construction, :class:`EkfConfig`). Equal to the dense
    products up to rounding (tests/estimation/test_ekf_sparse.py); see :func:`_covariance_step`."""
    (dt, _, _, _, _, _), _, _, (_, _, _, _, g01, g02), (_, _, _, _, g11, g12), (_, _, _, _, g21, g22) = G6.tolist()
    qd = np.asarray(Qf, dtype=float).copy()
    qd[0:3] += dt * dt * np.asarray(qu, dtype=float)[0:3]  # G Q_u G^T over p: dt^2 Q_v (diagonal)
    return _covariance_step(P, F3, dt, (g01, g02, g11, g12, g21, g22), qu[3:6].tolist(), qd)


def _covariance_step(
    P: np.ndarray, F3: np.ndarray, dt: float, gr: tuple[float, ...], qw: list[float], qd: np.ndarray
) -> np.ndarray:
    """Delivery eq 6, P <- F P F^T + G Q_u G^T + Q_f, written so that a symmetric P gives an
    exactly symmetric result (no re-symmetrisation needed afterwards):

    * F P F^T: F = I but for rows 3-5 (``F3``), so with A = F3 P only rows and columns 3-5 change:
      rows 3-5 are A, columns 3-5 (outside rows 3-5) are A^T (P symmetric), and the 3x3 block
      F3 P F3^T is symmetrised on floats.
    * G Q_u G^T is block diagonal (G = [dt I, 0; 0, J_r dt] above row 6, Q_u diagonal):
      dt^2 Q_v on p's diagonal and G_r Q_w G_r^T (G_r = J_r dt, entries ``gr``, Q_w = diag(``qw``))
      on the attitude block, each entry summed once and mirrored.
    * ``qd`` = the diagonal of Q_f with dt^2 Q_v added on p's three entries.
    """
    out = P.copy()
    A = out[3:6]
    F3.dot(P, out=A)  # rows 3-5 of F P (ndarray.dot: ~0.5 us less dispatch than @)
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = A.dot(F3.T).tolist()  # F3 P F3^T
    out[:, 3:6] = A.T  # columns 3-5 of F P F^T = (rows 3-5)^T; their 3x3 block is set below
    g01, g02, g11, g12, g21, g22 = gr  # G_r rows: [dt, g01, g02], [0, g11, g12], [0, g21, g22]
    q3, q4, q5 = qw
    # G_r Q_w: the rows scaled by Q_w's diagonal
    h00, h01, h02 = dt * q3, g01 * q4, g02 * q5
    h11, h12, h21, h22 = g11 * q4, g12 * q5, g21 * q4, g22 * q5
    c01 = 0.5 * (b01 + b10) + (h01 * g11 + h02 * g12)  # (F P F^T + G_r Q_w G_r^T), upper triangle
    c02 = 0.5 * (b02 + b20) + (h01 * g21 + h02 * g22)
    c12 = 0.5 * (b12 + b21) + (h11 * g21 + h12 * g22)
    out[3:6, 3:6] = (
        (b00 + (h00 * dt + h01 * g01 + h02 * g02), c01, c02),
        (c01, b11 + (h11 * g11 + h12 * g12), c12),
        (c02, c12, b22 + (h21 * g21 + h22 * g22)),
    )
    diagonal = out.reshape(-1)[:: N_STATES + 1]  # a view of the diagonal
    diagonal += qd  # Q_f, and dt^2 Q_v (G Q_u G^T over p)
    return out


def joseph_covariance(P: np.ndarray, K: np.ndarray, PHt: np.ndarray, S: np.ndarray) -> np.ndarray:
    """The Joseph form of delivery eq 8, (I - K H) P (I - K H)^T + K R K^T, from P H^T and
    S = H P H^T + R (so that the sparse H is never widened to 12 columns).

    Expanded it is P - K (P H^T)^T - (P H^T) K^T + K S K^T, exact for any gain K (not only the
    optimal one: a rounding error in K stays second order in P, the reason for the Joseph form),
    and regrouped as

        P + N + N^T,    N = (K S / 2 - P H^T) K^T

    (N + N^T = K (S + S^T)/2 K^T - K (P H^T)^T - (P H^T) K^T: S's symmetric part, so S needs no
    re-symmetrising). N + N^T is symmetric to the last bit, so a symmetric P gives an exactly
    symmetric result and the 12x12 matrix is never re-symmetrised. K S / 2 - P H^T is one BLAS
    call (dgemm with alpha = 1/2, beta = -1). Equal to the dense form to ~1e-9 relative
    (tests/estimation/test_ekf_sparse.py).
    """
    N = _gemm(0.5, K, S, -1.0, PHt).dot(K.T)
    return P + (N + N.T)


def h_sdk(x: np.ndarray, xi: float, with_angles: bool = True) -> np.ndarray:
    """Delivery eq 12: [p + xi b_p; r]."""
    pos = x[0:3] + xi * x[6:9]
    return np.concatenate([pos, x[3:6]]) if with_angles else pos


def jacobian_sdk(xi: float, with_angles: bool = True) -> np.ndarray:
    H = np.zeros((6 if with_angles else 3, N_STATES))
    H[0:3, 0:3] = np.eye(3)
    H[0:3, 6:9] = xi * np.eye(3)
    if with_angles:
        H[3:6, 3:6] = np.eye(3)
    return H


def h_uwb(x: np.ndarray) -> np.ndarray:
    """Delivery eq 15: p (the fix is mapped into world NED first)."""
    return x[0:3].copy()


def jacobian_uwb() -> np.ndarray:
    H = np.zeros((3, N_STATES))
    H[0:3, 0:3] = np.eye(3)
    return H


def _euler_of(M: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of a rotation matrix, ZYX (same as geometry.rotmat_to_euler)."""
    (m00, _, _), (m10, _, _), (m20, m21, m22) = M.tolist()  # Python floats: no numpy scalar per entry
    return np.array([math.atan2(m21, m22), -math.asin(max(-1.0, min(1.0, m20))), math.atan2(m10, m00)])


def h_aruco(x: np.ndarray, T_body_camera: Transform, T_world_marker: Transform) -> np.ndarray:
    """Delivery eqs 13-14: H_a^c = (H_c^d)^-1 (H_d^w)^-1 H_a^w as [position; ZYX Euler]."""
    R_wb = euler_to_rotmat(x[3], x[4], x[5])
    R_bc = T_body_camera.R
    pos = R_bc.T @ (R_wb.T @ (T_world_marker.t - x[0:3]) - T_body_camera.t)
    M = R_bc.T @ R_wb.T @ T_world_marker.R
    return np.concatenate([pos, _euler_of(M)])


def _euler_rotmat_derivatives(roll: float, pitch: float, yaw: float) -> tuple[np.ndarray, ...]:
    """dR/droll, dR/dpitch, dR/dyaw of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    dRx = np.array([[0.0, 0.0, 0.0], [0.0, -sr, -cr], [0.0, cr, -sr]])
    dRy = np.array([[-sp, 0.0, cp], [0.0, 0.0, 0.0], [-cp, 0.0, -sp]])
    dRz = np.array([[-sy, -cy, 0.0], [cy, -sy, 0.0], [0.0, 0.0, 0.0]])
    RzRy = Rz @ Ry
    return RzRy @ dRx, Rz @ dRy @ Rx, dRz @ Ry @ Rx


def jacobian_aruco(x: np.ndarray, T_body_camera: Transform, T_world_marker: Transform) -> np.ndarray:
    """Analytic d h_ArUco / dx (6x12): only p and r enter eqs 13-14."""
    R_wb = euler_to_rotmat(x[3], x[4], x[5])
    R_cb = T_body_camera.R.T
    R_wm = T_world_marker.R
    d = T_world_marker.t - x[0:3]
    M = R_cb @ R_wb.T @ R_wm
    H = np.zeros((6, N_STATES))
    H[0:3, 0:3] = -R_cb @ R_wb.T
    m20 = max(-1.0, min(1.0, M[2, 0]))
    den_roll = M[2, 1] ** 2 + M[2, 2] ** 2
    den_yaw = M[1, 0] ** 2 + M[0, 0] ** 2
    den_pitch = math.sqrt(max(1.0 - m20 * m20, 1e-300))
    for k, dR in enumerate(_euler_rotmat_derivatives(x[3], x[4], x[5])):
        dRt = dR.T
        H[0:3, 3 + k] = R_cb @ (dRt @ d)
        dM = R_cb @ dRt @ R_wm
        H[3, 3 + k] = (M[2, 2] * dM[2, 1] - M[2, 1] * dM[2, 2]) / den_roll
        H[4, 3 + k] = -dM[2, 0] / den_pitch
        H[5, 3 + k] = (M[0, 0] * dM[1, 0] - M[1, 0] * dM[0, 0]) / den_yaw
    return H


def aruco_model(x: np.ndarray, T_body_camera: Transform, T_world_marker: Transform) -> tuple[np.ndarray, np.ndarray]:
    """h_ArUco (delivery eqs 13-14) and its Jacobian in one pass, the Jacobian as its only
    non-zero block: the 6x6 d h / d(p, r) (the same values as :func:`h_aruco` and
    :func:`jacobian_aruco`, up to rounding).

    With C = R_cb R_wb^T and M = C R_wm, the Euler derivatives are dR_wb/d angle_k = [a_k]x R_wb,
    a_k the k-th Euler-rate axis in the world (roll: R_wb e_x, pitch: Rz(yaw) e_y, yaw: e_z), so
    with b_k = C a_k: d(C d)/d angle_k = (C d) x b_k and dM/d angle_k = -[b_k]x M.
    """
    xl = x.tolist()
    roll, pitch, yaw = xl[3], xl[4], xl[5]
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    # Plain floats throughout: numpy's per-call cost (~1 us) exceeds a 3x3 product's arithmetic.
    # Every product is summed over k = 0, 1, 2 in order, as numpy's 3x3 matmul does without FMA
    # (the pinned arithmetic of the golden flight digests), so the floats are those of the numpy
    # form (tests/estimation/test_ekf_sparse.py).
    # R_wb = Rz(yaw) Ry(pitch) Rx(roll), as geometry.euler_to_rotmat
    w00, w01, w02 = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    w10, w11, w12 = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    w20, w21, w22 = -sp, cp * sr, cp * cr
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = T_body_camera.R.tolist()  # R_bc = R_cb^T
    # C = R_cb R_wb^T: C_ij = sum_k R_bc[k, i] R_wb[j, k]
    c00 = b00 * w00 + b10 * w01 + b20 * w02
    c01 = b00 * w10 + b10 * w11 + b20 * w12
    c02 = b00 * w20 + b10 * w21 + b20 * w22
    c10 = b01 * w00 + b11 * w01 + b21 * w02
    c11 = b01 * w10 + b11 * w11 + b21 * w12
    c12 = b01 * w20 + b11 * w21 + b21 * w22
    c20 = b02 * w00 + b12 * w01 + b22 * w02
    c21 = b02 * w10 + b12 * w11 + b22 * w12
    c22 = b02 * w20 + b12 * w21 + b22 * w22
    tw0, tw1, tw2 = T_world_marker.t.tolist()
    d0, d1, d2 = tw0 - xl[0], tw1 - xl[1], tw2 - xl[2]  # d = t_wm - p
    q0 = c00 * d0 + c01 * d1 + c02 * d2  # q = C d: the marker in the camera, before the lens offset
    q1 = c10 * d0 + c11 * d1 + c12 * d2
    q2 = c20 * d0 + c21 * d1 + c22 * d2
    tb0, tb1, tb2 = T_body_camera.t.tolist()
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = T_world_marker.R.tolist()
    # M = C R_wm, the marker's attitude in the camera
    m00 = c00 * r00 + c01 * r10 + c02 * r20
    m01 = c00 * r01 + c01 * r11 + c02 * r21
    m02 = c00 * r02 + c01 * r12 + c02 * r22
    m10 = c10 * r00 + c11 * r10 + c12 * r20
    m11 = c10 * r01 + c11 * r11 + c12 * r21
    m12 = c10 * r02 + c11 * r12 + c12 * r22
    m20 = c20 * r00 + c21 * r10 + c22 * r20
    m21 = c20 * r01 + c21 * r11 + c22 * r21
    m22 = c20 * r02 + c21 * r12 + c22 * r22
    m20c = max(-1.0, min(1.0, m20))
    hx = np.array(
        [
            q0 - (b00 * tb0 + b10 * tb1 + b20 * tb2),  # eq 13 position: C d - R_cb t_bc
            q1 - (b01 * tb0 + b11 * tb1 + b21 * tb2),
            q2 - (b02 * tb0 + b12 * tb1 + b22 * tb2),
            math.atan2(m21, m22),  # eq 14, ZYX Euler angles of M
            -math.asin(m20c),
            math.atan2(m10, m00),
        ]
    )
    C = (c00, c01, c02, c10, c11, c12, c20, c21, c22)
    M = (m00, m01, m02, m10, m11, m12, m20, m21, m22)
    return hx, _aruco_jacobian_block(C, M, (q0, q1, q2), m20c, (cp, sp, cy, sy))


def _aruco_jacobian_block(
    C: tuple[float, ...],
    M: tuple[float, ...],
    q: tuple[float, float, float],
    m20c: float,
    pitch_yaw: tuple[float, float, float, float],
) -> np.ndarray:
    """:func:`aruco_model`'s 6x6 d h / d(p, r) from C = R_cb R_wb^T, M = C R_wm and q = C d (each
    row by row), M[2, 0] clipped to [-1, 1] and (cos, sin) of pitch and yaw."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = C
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = M
    q0, q1, q2 = q
    cp, sp, cy, sy = pitch_yaw
    # b_k = C a_k, a_k the columns of [[cy cp, -sy, 0], [sy cp, cy, 0], [-sp, 0, 1]] (zero terms left out)
    a00, a10 = cy * cp, sy * cp
    B0 = (c00 * a00 + c01 * a10 + c02 * -sp, c00 * -sy + c01 * cy, c02)  # first components of b_0, b_1, b_2
    B1 = (c10 * a00 + c11 * a10 + c12 * -sp, c10 * -sy + c11 * cy, c12)
    B2 = (c20 * a00 + c21 * a10 + c22 * -sp, c20 * -sy + c21 * cy, c22)
    den_roll = m21 * m21 + m22 * m22
    den_pitch = math.sqrt(max(1.0 - m20c * m20c, 1e-300))
    den_yaw = m10 * m10 + m00 * m00
    # H = [d h/dp (-C in rows 0-2, 0 below) | d h/d(roll, pitch, yaw)], gathered column by column
    # (the rows of H^T: one flat list, one array, no nested lists to parse)
    Ht = [-c00, -c10, -c20, 0.0, 0.0, 0.0, -c01, -c11, -c21, 0.0, 0.0, 0.0, -c02, -c12, -c22, 0.0, 0.0, 0.0]
    for b0, b1, b2 in zip(B0, B1, B2, strict=True):  # b_k, k = roll, pitch, yaw
        # the entries of dM_k = -[b_k]x M that the Euler angles of M (eq 14) need
        dM00 = b2 * m10 - b1 * m20
        dM10 = b0 * m20 - b2 * m00
        dM20 = b1 * m00 - b0 * m10
        dM21 = b1 * m01 - b0 * m11
        dM22 = b1 * m02 - b0 * m12
        Ht += (
            q1 * b2 - q2 * b1,  # d(C d)/d angle_k = (C d) x b_k
            q2 * b0 - q0 * b2,
            q0 * b1 - q1 * b0,
            (m22 * dM21 - m21 * dM22) / den_roll,  # d roll(M) / d angle_k
            -dM20 / den_pitch,  # d pitch(M) / d angle_k
            (m00 * dM10 - m10 * dM00) / den_yaw,  # d yaw(M) / d angle_k
        )
    return np.array(Ht).reshape(6, 6).T


# ----------------------------------------------------------------------------------------------


class EkfSnapshot(NamedTuple):
    """Everything needed to put the filter back exactly where it was. (Immutable; a named tuple
    rather than a frozen dataclass: the delayed-measurement buffer takes one per event, and a
    frozen dataclass's ``__init__`` costs ~2 us, a named tuple's ~0.3 us.)"""

    x: np.ndarray
    P: np.ndarray
    xi: bool
    initialized: bool
    last_input: np.ndarray
    counters: dict[str, int]
    consecutive_rejections: dict[EkfSensor, int]


class DeliveryEkf:
    """The 12-state EKF (delivery eqs 5-15). Synchronous, no clock: ``predict`` takes dt.

    ``pad_down_m`` is the pad's down coordinate in world NED; the height above the pad
    (pad_down_m - p_down) scales the measurement noise and gates ArUco at 30 m.
    Without ``x0`` the first SDK pose initialises position (and attitude, if given) directly;
    pad-local measurements before that are refused (a far-off linearisation point would make
    the first, xi-switching update meaningless).
    For measurements stamped in the past use :class:`DelayedMeasurementBuffer`.
    """

    def __init__(
        self,
        config: EkfConfig | None = None,
        T_body_camera: Transform | None = None,
        x0: ArrayLike | None = None,
        P0: ArrayLike | None = None,
        pad_down_m: float = 0.0,
    ) -> None:
        self.config = cfg = config or EkfConfig()
        self.T_body_camera = T_body_camera or Transform.identity()
        self.pad_down_m = float(pad_down_m)
        self.x = np.zeros(N_STATES) if x0 is None else np.asarray(x0, dtype=float).reshape(N_STATES).copy()
        if P0 is None:
            self.P = np.diag(
                [cfg.initial_position_sigma_m**2] * 3
                + [cfg.initial_angle_sigma_rad**2] * 3
                + [cfg.initial_gps_bias_sigma_m**2] * 3
                + [cfg.initial_gyro_bias_sigma_rad_s**2] * 3
            )
        else:
            P0a = np.asarray(P0, dtype=float).reshape(N_STATES, N_STATES)
            self.P = (P0a + P0a.T) * 0.5  # exactly symmetric from the start: the steps keep it so
        if not (np.all(np.isfinite(self.x)) and np.all(np.isfinite(self.P))):
            raise ValueError("x0 and P0 must be finite")
        self.xi = False  # delivery eq 12: pad-local data (ArUco or UWB) observed yet?
        self.initialized = x0 is not None
        self.consecutive_rejections = dict.fromkeys(SENSORS, 0)
        self.last_input = np.zeros(6)
        self._Qu = np.diag([cfg.input_velocity_sigma_m_s**2] * 3 + [cfg.input_rate_sigma_rad_s**2] * 3)
        self._qu = self._Qu.diagonal().copy()  # Q_u is diagonal: eq 6 scales G's columns by it
        self._qf_density = np.array(
            [cfg.position_process_sigma_m_per_sqrt_s**2] * 3
            + [cfg.angle_process_sigma_rad_per_sqrt_s**2] * 3
            + [cfg.gps_bias_process_sigma_m_per_sqrt_s**2] * 3
            + [cfg.gyro_bias_process_sigma_rad_s_per_sqrt_s**2] * 3
        )
        self._qw = self._qu[3:6].tolist()  # Q_w, the rates' block of Q_u (eq 6's attitude noise)
        # predict's step length and the diagonal it adds for it: Q_f + dt^2 Q_v on p (eq 6)
        self._q_step, self._qd = math.nan, self._qf_density
        self._gate = {dof: chi2_ppf(cfg.gate_probability, dof) for dof in (3, 6)}
        self._H_uwb = jacobian_uwb()
        # h_ArUco and its Jacobian (the dense reference filter swaps in the separate functions)
        self._aruco_model_fn: Callable[[np.ndarray, Transform, Transform], tuple[np.ndarray, np.ndarray]] = aruco_model
        self.counters: dict[str, int] = {"input.nonfinite": 0, "predict.bad_dt": 0, "covariance.repairs": 0}
        for s in SENSORS:
            for o in UpdateOutcome:
                self.counters[f"{s.value}.{o.value}"] = 0
            self.counters[f"{s.value}.gate_resets"] = 0
        # the counter names (the enum's value property and an f-string cost ~1 us per update)
        self._counter_key = {(s, o): f"{s.value}.{o.value}" for s in SENSORS for o in UpdateOutcome}
        self._accepted_key = {s: f"{s.value}.{UpdateOutcome.ACCEPTED.value}" for s in SENSORS}
        self._gate_resets_key = {s: f"{s.value}.gate_resets" for s in SENSORS}

    # ---- bookkeeping ---------------------------------------------------------------------

    def snapshot(self) -> EkfSnapshot:
        return EkfSnapshot(
            self.x.copy(),
            self.P.copy(),
            self.xi,
            self.initialized,
            self.last_input.copy(),
            dict(self.counters),
            dict(self.consecutive_rejections),
        )

    def restore(self, snap: EkfSnapshot) -> None:
        self.x = snap.x.copy()
        self.P = snap.P.copy()
        self.xi = snap.xi
        self.initialized = snap.initialized
        self.last_input = snap.last_input.copy()
        self.counters = dict(snap.counters)
        self.consecutive_rejections = dict(snap.consecutive_rejections)

    @property
    def height_above_pad_m(self) -> float:
        return max(0.0, self.pad_down_m - float(self.x[2]))

    def estimate(self, time_s: float) -> StateEstimate:
        """The current state as a :class:`StateEstimate` (velocity: the last input, world NED)."""
        x, v = self.x, self.last_input
        return StateEstimate(
            time_s=time_s,
            north_m=float(x[0]),
            east_m=float(x[1]),
            down_m=float(x[2]),
            north_m_s=float(v[0]),
            east_m_s=float(v[1]),
            down_m_s=float(v[2]),
            roll_rad=float(x[3]),
            pitch_rad=float(x[4]),
            yaw_rad=float(x[5]),
            source="ekf",
            gps_bias_north_m=float(x[6]),
            gps_bias_east_m=float(x[7]),
            gps_bias_down_m=float(x[8]),
        )

    # ---- prediction (eqs 5, 6, 11) -------------------------------------------------------

    def predict(self, u: ArrayLike, dt_s: float) -> bool:
        """Propagate by ``dt_s`` with input u = [v_world (3), omega_body (3)] (eqs 5, 6, 11).

        A non-finite input is counted and replaced by the last finite one; a non-positive or
        non-finite dt is counted and ignored.
        """
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            if dt_s != 0.0:
                self.counters["predict.bad_dt"] += 1
            return False
        uu = np.asarray(u, dtype=float).reshape(6)
        ul = uu.tolist()
        if not all(map(math.isfinite, ul)):
            self.counters["input.nonfinite"] += 1
            ul = self.last_input.tolist()
        else:
            self.last_input = uu.copy()
        max_step = self.config.max_step_s
        n = 1 if dt_s <= max_step else math.ceil(dt_s / max_step - 1e-9)  # sub-steps of <= max_step
        h = dt_s / n
        if h != self._q_step:  # eq 6's diagonal for this step (the input rate's step, cached)
            qd = self._qf_density * h  # Q_f
            qd[0:3] += h * h * self._qu[0:3]  # G Q_u G^T over p: dt^2 Q_v
            self._q_step, self._qd = h, qd
        qd, qw = self._qd, self._qw
        # the state stays a list of floats through the sub-steps and the wrap: one array at the end
        xl = self.x.tolist()
        P = self.P
        for _ in range(n):
            F3, gr = _propagation_step(xl, ul, h)  # eq 5 with eq 11 (xl <- f(x, u, h))
            P = _covariance_step(P, F3, h, gr, qw, qd)  # eq 6 (exactly symmetric: no re-symmetrising)
        xl[3] = (xl[3] + math.pi) % _TWO_PI - math.pi
        xl[5] = (xl[5] + math.pi) % _TWO_PI - math.pi
        self.x = np.array(xl)
        self.P = P
        self._condition()
        return True

    def _dense_steps(self, u: ArrayLike, dt_s: float) -> tuple[np.ndarray, int, float] | None:
        """For a dense prediction (ekf_reference, moving_pad): the input (a non-finite one counted
        and replaced by the last finite one), the number of sub-steps and their length; None for a
        non-positive or non-finite dt (counted unless 0)."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            if dt_s != 0.0:
                self.counters["predict.bad_dt"] += 1
            return None
        uu = np.asarray(u, dtype=float).reshape(6)
        if not np.all(np.isfinite(uu)):
            self.counters["input.nonfinite"] += 1
            uu = self.last_input
        else:
            self.last_input = uu.copy()
        n = max(1, math.ceil(dt_s / self.config.max_step_s - 1e-9))
        return uu, n, dt_s / n

    # ---- corrections (eqs 7, 9 + Joseph form) --------------------------------------------

    def update_sdk(self, position_ned_m: ArrayLike, euler_rad: ArrayLike | None = None) -> UpdateOutcome:
        """Autopilot/GPS pose: delivery eq 12 (position + xi b_p, Euler angles)."""
        cfg = self.config
        pos = np.asarray(position_ned_m, dtype=float).reshape(3)
        with_angles = euler_rad is not None
        z = np.concatenate([pos, np.asarray(euler_rad, dtype=float).reshape(3)]) if with_angles else pos
        if not np.all(np.isfinite(z)):
            return self._count(EkfSensor.SDK, UpdateOutcome.REJECTED_NONFINITE)
        xi = 1.0 if self.xi else 0.0
        sp = cfg.sdk_position_sigma_m + cfg.sdk_position_sigma_gain_m_per_m * self.height_above_pad_m
        sig = [sp] * 3 + ([cfg.sdk_angle_sigma_rad] * 3 if with_angles else [])
        R = np.diag(np.square(sig))
        if not self.initialized:  # the first pose: take it as it is
            n = len(z)
            self.x[0:n] = z
            self.x[3] = (self.x[3] + math.pi) % _TWO_PI - math.pi
            self.x[5] = (self.x[5] + math.pi) % _TWO_PI - math.pi
            self.P[0:n, :] = 0.0
            self.P[:, 0:n] = 0.0
            self.P[0:n, 0:n] = R
            self.initialized = True
            return self._count(EkfSensor.SDK, UpdateOutcome.ACCEPTED)
        hx, H = h_sdk(self.x, xi, with_angles), jacobian_sdk(xi, with_angles)
        return self._update(EkfSensor.SDK, z, hx, H, R, with_angles)

    def update_aruco(self, T_camera_marker: Transform, T_world_marker: Transform) -> UpdateOutcome:
        """Marker pose from PnP, as measured (delivery eqs 13-14), diagonal R."""
        cfg = self.config
        (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(T_camera_marker.R, dtype=float).tolist()
        t0, t1, t2 = np.asarray(T_camera_marker.t, dtype=float).reshape(3).tolist()
        # one finiteness test: the angles of a finite R are finite (atan2, asin of a clamped value)
        if not all(map(math.isfinite, (m00, m01, m02, m10, m11, m12, m20, m21, m22, t0, t1, t2))):
            return self._count(EkfSensor.ARUCO, UpdateOutcome.REJECTED_NONFINITE)
        # z: the marker's position and ZYX Euler angles in the camera (eqs 13-14; as _euler_of)
        z = np.array((t0, t1, t2, math.atan2(m21, m22), -math.asin(max(-1.0, min(1.0, m20))), math.atan2(m10, m00)))
        height = self.height_above_pad_m
        if height > cfg.aruco_max_height_m:
            return self._count(EkfSensor.ARUCO, UpdateOutcome.REJECTED_HEIGHT)
        sp = cfg.aruco_position_sigma_m + cfg.aruco_position_sigma_gain_m_per_m * height
        sa = cfg.aruco_angle_sigma_gain_rad_per_m * height
        s_rp = cfg.aruco_roll_pitch_sigma_rad + sa
        s_y = cfg.aruco_yaw_sigma_rad + sa
        R = np.zeros((6, 6))
        R.reshape(-1)[::7] = (sp * sp, sp * sp, sp * sp, s_rp * s_rp, s_rp * s_rp, s_y * s_y)  # diagonal R
        T_bc = self.T_body_camera
        model = self._aruco_model_fn
        return self._local_update(EkfSensor.ARUCO, z, lambda x: model(x, T_bc, T_world_marker), R, True)

    def update_uwb(self, fix: PositionFix, T_world_anchor: Transform) -> UpdateOutcome:
        """A UWB fix in the anchor frame, mapped to world NED: delivery eq 15, h = p."""
        cfg = self.config
        p_a = np.array([fix.x_m, fix.y_m, fix.z_m], dtype=float)
        if not np.all(np.isfinite(p_a)):
            return self._count(EkfSensor.UWB, UpdateOutcome.REJECTED_NONFINITE)
        z = T_world_anchor.R @ p_a + T_world_anchor.t
        sigma = cfg.uwb_position_sigma_m + cfg.uwb_position_sigma_gain_m_per_m * self.height_above_pad_m
        pdop = float(fix.pdop)
        hdop = float(getattr(fix, "hdop", math.nan))
        vdop = float(getattr(fix, "vdop", math.nan))
        if (
            cfg.uwb_scale_with_pdop
            and bool(getattr(fix, "vertical_weak", False))
            and math.isfinite(hdop)
            and math.isfinite(vdop)
            and hdop > 0.0
            and vdop > 0.0
        ):
            # coplanar anchors: the vertical is weakly observed; per-axis variances in the anchor
            # frame (x, y share HDOP^2; z gets VDOP^2; their sum is PDOP^2 as in the isotropic
            # case), rotated into world NED
            R_a = np.diag([hdop * hdop / 2.0, hdop * hdop / 2.0, vdop * vdop]) * sigma * sigma
            R = T_world_anchor.R @ R_a @ T_world_anchor.R.T
        else:
            if cfg.uwb_scale_with_pdop and math.isfinite(pdop) and pdop > 0.0:
                sigma *= pdop / math.sqrt(3.0)
            R = np.eye(3) * sigma * sigma  # isotropic: invariant under the anchor->world rotation
        H = self._H_uwb[:, 0:3]  # eq 15 only sees p
        return self._local_update(EkfSensor.UWB, z, lambda x: (h_uwb(x), H), R, False)

    # ---- internals -----------------------------------------------------------------------

    def _gate_threshold(self, dof: int) -> float:
        gate = self._gate.get(dof)
        if gate is None:
            gate = self._gate[dof] = chi2_ppf(self.config.gate_probability, dof)
        return gate

    def _count(self, sensor: EkfSensor, outcome: UpdateOutcome) -> UpdateOutcome:
        self.counters[self._counter_key[sensor, outcome]] += 1
        return outcome

    def _local_update(
        self,
        sensor: EkfSensor,
        z: np.ndarray,
        model: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
        R: np.ndarray,
        has_angles: bool,
    ) -> UpdateOutcome:
        """A pad-local measurement (``model(x)``: h(x) and the first columns of its Jacobian);
        the first accepted one switches xi to 1 (see module doc)."""
        if not self.initialized:
            return self._count(sensor, UpdateOutcome.REJECTED_UNINITIALIZED)
        if self.xi:
            return self._update(sensor, z, *model(self.x), R, has_angles)
        saved_x, saved_P = self.x, self.P
        T = np.eye(saved_x.shape[0])  # the state's size: a subclass may append states
        T[0:3, 6:9] = -np.eye(3)  # p <- p - b_p
        self.x = T @ saved_x
        TPTt = T @ saved_P @ T.T
        self.P = (TPTt + TPTt.T) * 0.5  # exactly symmetric, as the update's Joseph form wants P
        outcome = self._update(sensor, z, *model(self.x), R, has_angles)
        if outcome is UpdateOutcome.ACCEPTED:
            self.xi = True
        else:
            self.x, self.P = saved_x, saved_P
        return outcome

    def _update(
        self, sensor: EkfSensor, z: np.ndarray, hx: np.ndarray, H: np.ndarray, R: np.ndarray, has_angles: bool
    ) -> UpdateOutcome:
        """Gate, then correct (eqs 7, 9) with the Joseph form of eq 8.

        ``H`` may hold only the first k columns of the Jacobian (the rest being zero: ArUco sees
        p and r, UWB p); the products then run over those columns only."""
        y = z - hx
        if has_angles:  # angle residuals wrapped to [-pi, pi); they are always rows 3-5
            # on Python floats: the same IEEE remainder as numpy's, without three array temporaries
            y3, y4, y5 = y[3:6].tolist()
            y[3:6] = (
                (y3 + math.pi) % _TWO_PI - math.pi,
                (y4 + math.pi) % _TWO_PI - math.pi,
                (y5 + math.pi) % _TWO_PI - math.pi,
            )
        k = H.shape[1]
        P = self.P
        # (ndarray.dot rather than @ for the products: the same BLAS calls, ~0.5 us less dispatch each)
        PHt = P[:, 0:k].dot(H.T)  # P H^T
        S = H.dot(PHt[0:k])
        S += R  # S = H P H^T + R (not re-symmetrised: potrf reads one triangle, the Joseph form below
        #         takes S's symmetric part by construction)
        L, info = _potrf(S, lower=1)  # Cholesky factor of S (its lower triangle): S must be positive definite
        if info != 0:
            return self._count(sensor, UpdateOutcome.REJECTED_NUMERICAL)
        d2 = float(y.dot(_potrs(L, y, lower=1)[0]))  # squared Mahalanobis distance y^T S^-1 y
        gate = self._gate.get(len(y)) or self._gate_threshold(len(y))
        if not math.isfinite(d2) or (self.config.gating_enabled and d2 > gate):
            self._note_gate_rejection(sensor)
            return self._count(sensor, UpdateOutcome.REJECTED_GATE)
        self.consecutive_rejections[sensor] = 0
        K = _potrs(L, PHt.T, lower=1)[0].T  # eq 9: K = P H^T S^-1 (two triangular solves, no inverse)
        xl = (self.x + K.dot(y)).tolist()  # eq 7
        xl[3] = (xl[3] + math.pi) % _TWO_PI - math.pi  # roll and yaw wrapped to [-pi, pi), on floats
        xl[5] = (xl[5] + math.pi) % _TWO_PI - math.pi
        self.x = np.array(xl)
        self.P = joseph_covariance(P, K, PHt, S)  # the Joseph form of eq 8 (exactly symmetric)
        self._condition()
        self.counters[self._accepted_key[sensor]] += 1
        return UpdateOutcome.ACCEPTED

    def _note_gate_rejection(self, sensor: EkfSensor) -> None:
        """Count consecutive gate rejections; after too many, inflate what the sensor disputes."""
        cfg = self.config
        self.consecutive_rejections[sensor] += 1
        if (
            cfg.gate_reset_after_rejections <= 0
            or self.consecutive_rejections[sensor] < cfg.gate_reset_after_rejections
        ):
            return
        self.consecutive_rejections[sensor] = 0
        self.counters[self._gate_resets_key[sensor]] += 1
        if not self.xi:
            blocks = [P_IDX]  # before xi every sensor measures p (p is the GPS-frame position)
        elif sensor is EkfSensor.SDK:
            blocks = [BP_IDX]  # GPS disagrees with the pad-local estimate: the bias moved
        else:
            blocks = [P_IDX, BP_IDX]  # the pad sensor disagrees: p (and with it b_p) is lost
        for b in blocks:
            sig = cfg.initial_gps_bias_sigma_m if b == BP_IDX else cfg.initial_position_sigma_m
            self.P[b, :] = 0.0
            self.P[:, b] = 0.0
            self.P[b, b] = np.eye(3) * sig * sig

    @property
    def input_noise_variances(self) -> np.ndarray:
        """Q_u's diagonal (delivery eq 6; a copy): the input velocity's (m/s)^2 on N, E, D, then
        the input rates' (rad/s)^2 on roll, pitch, yaw."""
        return self._qu.copy()

    @property
    def process_noise_density(self) -> np.ndarray:
        """Q_f's diagonal per second (a copy): position m^2/s, angles rad^2/s, GPS bias m^2/s,
        gyro bias (rad/s)^2/s, three each."""
        return self._qf_density.copy()

    def _condition(self) -> None:
        """Floor P's diagonal at ``min_variance`` (counted as a repair). P's symmetry needs no
        repair: every step keeps a symmetric P exactly symmetric (eq 6 mirrors its changed rows
        into the columns, the Joseph form adds N + N^T, the xi switch and ``P0`` are symmetrised)."""
        P = self.P
        mv = self.config.min_variance
        # a cheap screen on Python floats first: min() is below mv, or NaN, only when some variance
        # is below mv or NaN; then the exact array test (NaN compares False: not repaired)
        if not min(P.diagonal().tolist()) >= mv:
            idx = np.flatnonzero(P.diagonal() < mv)
            if idx.size:
                self.counters["covariance.repairs"] += 1
                P = P.copy()  # (a new array: a snapshot may hold the old one)
                P[idx, idx] = mv
                self.P = P
