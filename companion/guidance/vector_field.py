"""Artificial vector field for path following (delivery eqs 18-19, Goncalves et al. 2010).

The field depends only on position, not time: after a link outage or a gust the vehicle
resumes from wherever it is, without the transient a time-based reference would produce.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.geometry.rotations import FloatArray
from companion.guidance.path import DeliveryPath


@dataclass(frozen=True)
class FieldSample:
    """The field at one point, in F_I."""

    velocity: FloatArray  # F(p), m/s
    sector: int
    lyapunov: float  # V
    speed_ref_m_s: float  # v_r


class VectorField:
    """F(p) = v_r (G F_conv + H F_tang) (delivery eq 19).

    ``s = +1`` delivers (start -> pad), ``s = -1`` returns (pad -> start).
    """

    def __init__(self, path: DeliveryPath, sector_speed_m_s: tuple[float, ...], k_f: float):
        if len(sector_speed_m_s) != 5 or any(not (v > 0 and math.isfinite(v)) for v in sector_speed_m_s):
            raise ValueError(f"sector_speed_m_s must be five positive speeds, got {sector_speed_m_s}")
        if not (k_f > 0 and math.isfinite(k_f)):
            raise ValueError(f"k_f = {k_f}: must be > 0")
        self.path = path
        self.v = tuple(float(v) for v in sector_speed_m_s)
        self.k_f = float(k_f)

    def __call__(self, p: ArrayLike, s: int = 1, speed_scale: float = 1.0) -> FieldSample:
        if s not in (1, -1):
            raise ValueError(f"s must be +1 (deliver) or -1 (return), got {s}")
        a1, a2, g1, g2, k = self.path.alphas(p)
        V = 0.5 * a1 * a1 + 0.5 * a2 * a2
        gradV = a1 * g1 + a2 * g2  # grad V = a1 grad a1 + a2 grad a2
        n_grad = float(np.linalg.norm(gradV))
        # eq 18; on the curve grad V = 0 and G = 0, so the convergent term vanishes anyway
        f_conv = gradV / n_grad if n_grad > 1e-12 else np.zeros(3)
        cross = np.cross(g1, g2)
        f_tang = s * cross / float(np.linalg.norm(cross))  # g1 = y-hat is never parallel to g2
        G = -(2.0 / math.pi) * math.atan(self.k_f * math.sqrt(V))  # G(V), in (-1, 0]
        H = math.sqrt(max(0.0, 1.0 - G * G))  # H(V) = sqrt(1 - G^2)
        v_r = self.v[k - 1] * speed_scale  # v_r(p) = v_i for p in S_i
        return FieldSample(v_r * (G * f_conv + H * f_tang), k, V, v_r)  # eq 19
