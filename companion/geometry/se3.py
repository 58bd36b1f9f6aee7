"""Rigid transforms in SE(3). ``T_a_b`` is the pose of frame b in frame a."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.geometry.rotations import (
    FloatArray,
    euler_to_rotmat,
    rotmat_to_euler,
)


@dataclass(frozen=True, eq=False)
class Transform:
    """A rigid transform: x_a = R @ x_b + t."""

    R: FloatArray
    t: FloatArray

    @staticmethod
    def identity() -> Transform:
        return Transform(np.eye(3), np.zeros(3))

    @staticmethod
    def from_euler(position: ArrayLike, roll: float, pitch: float, yaw: float) -> Transform:
        return Transform(euler_to_rotmat(roll, pitch, yaw), np.asarray(position, dtype=float))

    @staticmethod
    def from_matrix(H: ArrayLike) -> Transform:
        m = np.asarray(H, dtype=float)
        if m.shape != (4, 4):
            raise ValueError(f"homogeneous matrix must be 4x4, got {m.shape}")
        return Transform(m[:3, :3].copy(), m[:3, 3].copy())

    def matrix(self) -> FloatArray:
        H = np.eye(4)
        H[:3, :3] = self.R
        H[:3, 3] = self.t
        return H

    def inverse(self) -> Transform:
        Rt = self.R.T
        return Transform(Rt, -Rt @ self.t)

    def __matmul__(self, other: Transform) -> Transform:
        """Composition: T_a_b @ T_b_c = T_a_c."""
        return Transform(self.R @ other.R, self.R @ other.t + self.t)

    def apply(self, points: ArrayLike) -> FloatArray:
        p = np.asarray(points, dtype=float)
        return p @ self.R.T + self.t

    def euler(self) -> tuple[float, float, float]:
        return rotmat_to_euler(self.R)
