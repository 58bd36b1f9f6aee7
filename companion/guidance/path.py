"""The 5-section delivery path and its sectors (delivery section 4.1, eq 1; eqs 16-17).

All coordinates here are in the mission frame F_I: origin at the pad, x towards the pad from
the start, z up. The start is p_s = (-d, 0, z_s); the pad is p_f = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.geometry.rotations import FloatArray


class PathGeometryError(ValueError):
    """The requested path cannot be built (arcs do not fit, start on the pad, ...)."""


@dataclass(frozen=True)
class DeliveryPath:
    """Path parameters: h (cruise height), r (arc radius), d (horizontal start-pad distance)."""

    h: float
    r: float
    d: float

    def __post_init__(self) -> None:
        for name in ("h", "r", "d"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise PathGeometryError(f"path {name} = {v}: must be finite")
        if self.r <= 0.0:
            raise PathGeometryError(f"arc radius r = {self.r} m: must be > 0")
        if self.r >= self.h:
            raise PathGeometryError(f"arc radius r = {self.r} m must be < height h = {self.h} m")
        if self.d < 2.0 * self.r:
            raise PathGeometryError(
                f"start-pad distance d = {self.d:.2f} m must be >= 2 r = {2 * self.r} m: "
                "the two arcs must fit between start and pad"
            )

    def sector(self, p: ArrayLike) -> int:
        """Sector index 1..5 of point p (delivery eq 1)."""
        v = np.asarray(p, dtype=float)
        return self._sector(float(v[0]), float(v[2]))

    def _sector(self, x: float, z: float) -> int:
        h, r, d = self.h, self.r, self.d
        if z <= h - r:
            return 1 if x <= -d / 2.0 else 5
        if x < -d + r:
            return 2
        if x <= -r:
            return 3
        return 4

    def alphas(self, p: ArrayLike) -> tuple[float, float, FloatArray, FloatArray, int]:
        """alpha_1, alpha_2 (eqs 16-17), their gradients and the sector of p."""
        v = np.asarray(p, dtype=float)
        x, y, z = float(v[0]), float(v[1]), float(v[2])
        h, r, d = self.h, self.r, self.d
        k = self._sector(x, z)
        a1 = y  # eq 16
        g1 = np.array([0.0, 1.0, 0.0])
        if k == 1:
            a2 = -x - d
            g2 = np.array([-1.0, 0.0, 0.0])
        elif k in (2, 4):
            cx = -d + r if k == 2 else -r  # arc centres (x, h - r)
            dx, dz = x - cx, z - (h - r)
            rho = math.hypot(dx, dz)
            a2 = rho - r
            # grad of rho: unit vector from the centre; at the centre (never on the path) any
            # unit direction is a valid sub-gradient, pick the one pointing up.
            g2 = np.array([dx / rho, 0.0, dz / rho]) if rho > 1e-9 else np.array([0.0, 0.0, 1.0])
        elif k == 3:
            a2 = z - h
            g2 = np.array([0.0, 0.0, 1.0])
        else:
            a2 = x
            g2 = np.array([1.0, 0.0, 0.0])
        return a1, a2, g1, g2, k

    def lyapunov(self, p: ArrayLike) -> float:
        """V = alpha_1^2/2 + alpha_2^2/2 (below eq 18); sqrt(2V) is the distance to the curve
        near the path."""
        a1, a2, _, _, _ = self.alphas(p)
        return 0.5 * a1 * a1 + 0.5 * a2 * a2

    def distance_to_path(self, p: ArrayLike) -> float:
        return math.sqrt(2.0 * self.lyapunov(p))

    def distance_in_plane(self, p: ArrayLike) -> float:
        """The distance within the path's vertical plane: the lateral alpha_1 = y of eq 16 left
        out (along the path and up only)."""
        q = np.array(p, dtype=float)
        q[1] = 0.0
        return self.distance_to_path(q)

    def sample(self, step_m: float = 0.25, z_start: float = 0.0) -> FloatArray:
        """Points along the planned curve from the start (at height z_start) to the pad."""
        h, r, d = self.h, self.r, self.d
        pts: list[tuple[float, float, float]] = []

        def line(a: tuple[float, float], b: tuple[float, float]) -> None:
            n = max(2, math.ceil(math.dist(a, b) / step_m))
            for i in range(n):
                t = i / n
                pts.append((a[0] + t * (b[0] - a[0]), 0.0, a[1] + t * (b[1] - a[1])))

        def arc(cx: float, th0: float, th1: float) -> None:
            n = max(2, math.ceil(abs(th1 - th0) * r / step_m))
            for i in range(n):
                th = th0 + (th1 - th0) * i / n
                pts.append((cx + r * math.cos(th), 0.0, h - r + r * math.sin(th)))

        line((-d, z_start), (-d, h - r))
        arc(-d + r, math.pi, math.pi / 2)
        line((-d + r, h), (-r, h))
        arc(-r, math.pi / 2, 0.0)
        line((0.0, h - r), (0.0, 0.0))
        pts.append((0.0, 0.0, 0.0))
        return np.array(pts)
