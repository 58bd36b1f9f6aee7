"""Rotations: Euler ZYX (roll, pitch, yaw), rotation matrices and Hamilton quaternions (w,x,y,z).

``R = euler_to_rotmat(roll, pitch, yaw)`` is R_world_body: it maps body-frame vectors into the
world frame, R = Rz(yaw) @ Ry(pitch) @ Rx(roll).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def wrap_angle(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi) (exact for angles already in range)."""
    if -math.pi <= angle_rad < math.pi:
        return angle_rad
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def rot_x(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotvec_to_rotmat(rotvec: ArrayLike) -> FloatArray:
    """The rotation matrix of a rotation vector (axis times angle, rad), by Rodrigues' formula
    R = I + sin(a) K + (1 - cos(a)) K^2, K the cross-product matrix of the unit axis."""
    v = np.asarray(rotvec, dtype=float).reshape(3)
    angle = float(np.linalg.norm(v))
    if angle == 0.0:
        return np.eye(3)
    x, y, z = (v / angle).tolist()
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def align_to_z(direction: ArrayLike) -> FloatArray:
    """The smallest rotation taking the unit vector ``direction`` onto the z axis (identity when
    it is the z axis; a half turn about x when it is minus z)."""
    d = np.asarray(direction, dtype=float).reshape(3)
    d = d / float(np.linalg.norm(d))
    axis = np.array([d[1], -d[0], 0.0])  # d x z
    s = float(np.hypot(d[0], d[1]))
    if s == 0.0:
        return np.eye(3) if d[2] > 0.0 else np.diag([1.0, -1.0, -1.0])
    return rotvec_to_rotmat(axis / s * math.atan2(s, float(d[2])))


def euler_to_rotmat(roll: float, pitch: float, yaw: float) -> FloatArray:
    """R_world_body for ZYX Euler angles: Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rotmat_to_euler(R: ArrayLike) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of a rotation matrix, ZYX convention; pitch in [-pi/2, pi/2]."""
    m = np.asarray(R, dtype=float)
    pitch = -math.asin(max(-1.0, min(1.0, float(m[2, 0]))))
    roll = math.atan2(float(m[2, 1]), float(m[2, 2]))
    yaw = math.atan2(float(m[1, 0]), float(m[0, 0]))
    return roll, pitch, yaw


def euler_rates_matrix(roll: float, pitch: float) -> FloatArray:
    """J_r: maps body rates (p, q, r) to Euler angle rates (delivery eq 11, ZYX convention).

    d/dt [roll, pitch, yaw] = J_r(roll, pitch) @ [p, q, r]. Singular at pitch = +-90 deg.
    """
    sr, cr = math.sin(roll), math.cos(roll)
    cp = math.cos(pitch)
    tp = math.tan(pitch)
    return np.array(
        [
            [1.0, sr * tp, cr * tp],
            [0.0, cr, -sr],
            [0.0, sr / cp, cr / cp],
        ]
    )


def quat_normalize(q: ArrayLike) -> FloatArray:
    v = np.asarray(q, dtype=float)
    n = float(np.linalg.norm(v))
    if not math.isfinite(n) or n == 0.0:
        raise ValueError(f"cannot normalise quaternion {v!r}: norm is {n}")
    out = v / n
    # keep w >= 0 so equal rotations have one representation
    return out if out[0] >= 0.0 else -out


def quat_multiply(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Hamilton product a * b (apply b first, then a)."""
    aw, ax, ay, az = np.asarray(a, dtype=float)
    bw, bx, by, bz = np.asarray(b, dtype=float)
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def quat_conjugate(q: ArrayLike) -> FloatArray:
    w, x, y, z = np.asarray(q, dtype=float)
    return np.array([w, -x, -y, -z])


def quat_to_rotmat(q: ArrayLike) -> FloatArray:
    # quat_normalize on Python floats (numpy scalars cost ~0.1 us an operation): the norm as
    # np.linalg.norm computes it (sqrt of v.dot(v)), then the same divisions and sign flip
    v = np.asarray(q, dtype=float).reshape(4)
    n = math.sqrt(float(v.dot(v)))
    if not math.isfinite(n) or n == 0.0:
        raise ValueError(f"cannot normalise quaternion {v!r}: norm is {n}")
    w, x, y, z = v.tolist()
    w, x, y, z = w / n, x / n, y / n, z / n
    if not w >= 0.0:  # keep w >= 0 so equal rotations have one representation
        w, x, y, z = -w, -x, -y, -z
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotmat_to_quat(R: ArrayLike) -> FloatArray:
    """Shepperd's method: numerically safe for every rotation."""
    m = np.asarray(R, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    return quat_normalize(q)


def euler_to_quat(roll: float, pitch: float, yaw: float) -> FloatArray:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return quat_normalize(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def quat_to_euler(q: ArrayLike) -> tuple[float, float, float]:
    return rotmat_to_euler(quat_to_rotmat(q))


def quat_rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """Rotate vector v (body) by q (R_world_body) into the world frame."""
    return quat_to_rotmat(q) @ np.asarray(v, dtype=float)
