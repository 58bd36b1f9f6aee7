"""The fix's geometry for one anchor layout: its dilutions, gated, and the coplanar anchors' plane.

Anchors at different heights: the fix's PDOP/HDOP/VDOP are those of the linearised problem
(:func:`companion.uwb.solver.dilutions_of_precision`), gated on PDOP (TDoA too).

Anchors at one height (coplanar layouts, :attr:`AnchorLayout.coplanar`): the ranges fit the tag
and its mirror image through their plane equally well; the solution on the layout's ``tag_side``
is kept (:meth:`FixGeometry.on_tag_side`). Such a TWR fix is gated on the dilution in the
anchors' plane (HDOP for anchors at one height), not on PDOP: a tag at (or near) the plane, or
ranges slightly too short for any height so that the fitted height collapses onto the plane,
still has a well-determined horizontal. There the linearised VDOP diverges; the reported VDOP is
a second-order bound instead (h enters the ranges as h^2, see :meth:`FixGeometry.at`), so the EKF
hardly uses that vertical. TDoA on coplanar anchors keeps the PDOP gate (its unknown offset
absorbs the height wherever the anchors are about equidistant, at any height).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.config import MultilaterationConfig  # [landing.multilateration], declared there
from companion.uwb.anchors import AnchorLayout
from companion.uwb.linalg import inv
from companion.uwb.models import MeasurementModel, model_jacobian
from companion.uwb.solver import dilutions_of_cov


@dataclass(frozen=True)
class Geometry:
    """Dilutions of a fix (anchor frame) and the Jacobian its consistency check uses."""

    pdop: float
    hdop: float
    vdop: float
    #: the gated figure: PDOP, or for coplanar anchors the dilution in their plane
    gate_dop: float
    gate_name: str
    jacobian: np.ndarray


class FixGeometry:
    """The dilutions of a fix on ``layout`` and, for coplanar anchors, their plane and the tag's side.

    Keeps the last (J, (J^T J)^-1) at a fix: the consistency check and the dilutions of one fix
    need the same pair (keyed by the fix, the anchors and the model).
    """

    def __init__(self, layout: AnchorLayout, config: MultilaterationConfig) -> None:
        self.config = config
        self.coplanar = layout.coplanar
        self.side_normal = layout.tag_side_normal if self.coplanar else None
        self.plane_point = layout.plane_point_m
        self.plane_basis: np.ndarray | None = None
        if self.side_normal is not None:
            n = self.side_normal
            e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
            if np.linalg.norm(e1) < 0.5:
                e1 = np.array([0.0, 1.0, 0.0]) - n[1] * n
            e1 = e1 / np.linalg.norm(e1)
            self.plane_basis = np.column_stack([e1, np.cross(n, e1), n])  # in-plane e1, e2; normal
        self._jc_key: tuple[bytes, bytes, str] | None = None
        self._jc: tuple[np.ndarray, np.ndarray | None] = (np.zeros((0, 3)), None)

    def jacobian_cov(
        self, theta: np.ndarray, anchors: np.ndarray, model: MeasurementModel
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """J = :func:`model_jacobian` at ``theta`` and (J^T J)^-1 (None if singular), computed once
        per fix (the same floats each time, so reusing them changes nothing)."""
        key = (theta.tobytes(), anchors.tobytes(), model.name)
        if key != self._jc_key:
            J = model_jacobian(theta, anchors, model)
            self._jc = (J, inv(J.T.dot(J)))
            self._jc_key = key
        return self._jc

    def plane_jacobian(self, theta: np.ndarray, anchors: np.ndarray) -> np.ndarray:
        """Coplanar anchors, TWR: the Jacobian in (e1, e2, u), e1/e2 spanning the anchors' plane and
        u = h^2 the squared distance from it, with the anchors projected onto the plane.

        d_i = sqrt(rho_i^2 + u) has dd_i/du = 1/(2 d_i), finite at h = 0, where the z column of
        the usual Jacobian vanishes; for h > 0 this is a reparametrisation of the third
        coordinate, so the in-plane block of the covariance and the leverages are unchanged.
        """
        assert self.plane_basis is not None
        B = self.plane_basis
        n = B[:, 2]
        x = theta[:3]
        h = float((x - self.plane_point) @ n)
        q = (x - anchors) - np.outer((x - anchors) @ n, n)  # in-plane offsets to the projected anchors
        d = np.maximum(np.sqrt(np.sum(q**2, axis=1) + h * h), 1e-9)
        return np.column_stack([(q @ B[:, 0]) / d, (q @ B[:, 1]) / d, 0.5 / d])

    def at(self, theta: np.ndarray, anchors: np.ndarray, model: MeasurementModel) -> Geometry:
        """The fix's dilutions. Anchors at different heights: PDOP/HDOP/VDOP of the linearised
        problem, gated on PDOP (unchanged; TDoA too). Coplanar anchors, TWR: gated on the dilution
        in their plane (HDOP for anchors at one height); the vertical is weak by design and
        reported by VDOP.

        At the anchors' plane (h -> 0) the linearised VDOP diverges although the horizontal is
        well determined: h enters the ranges only as u = h^2, whose standard deviation is
        sigma_u = sigma_r sqrt(var_u) (``plane_jacobian``); a range error of sigma_r therefore
        moves the height by about sqrt(sigma_u) -- a distance that does not vanish at the plane.
        The reported VDOP is the smaller of the linearised one and this second-order bound
        sqrt(sigma_u)/sigma_r = sqrt(sqrt(var_u)/sigma_r) (sigma_r: ``range_sigma_m``). Away from
        the plane the linearised figure is the smaller one and is kept bit for bit.
        """
        J, cov = self.jacobian_cov(theta, anchors, model)
        pdop, hdop, vdop = dilutions_of_cov(cov)  # dilutions_of_precision(theta, anchors, model)
        if not (self.coplanar and model.plane_gated):  # (TDoA on coplanar anchors: MeasurementModel)
            return Geometry(pdop, hdop, vdop, pdop, "PDOP", J)
        assert self.plane_basis is not None
        Ju = self.plane_jacobian(theta, anchors)
        try:
            cov_u = np.linalg.inv(Ju.T @ Ju)
        except np.linalg.LinAlgError:
            inf = math.inf
            return Geometry(inf, inf, inf, inf, "HDOP (in the anchors' plane)", Ju)
        d = np.diag(cov_u)
        if not (np.all(np.isfinite(d[:3])) and np.all(d[:3] > 0.0)):
            inf = math.inf
            return Geometry(inf, inf, inf, inf, "HDOP (in the anchors' plane)", Ju)
        plane_dop = math.sqrt(float(d[0] + d[1]))
        bound = math.sqrt(math.sqrt(float(d[2])) / self.config.range_sigma_m)
        if vdop <= bound:  # the linearisation holds: the figures as they always were
            return Geometry(pdop, hdop, vdop, plane_dop, "HDOP (in the anchors' plane)", J)
        # at the plane: the in-plane block from (e1, e2, u), the normal direction from the bound,
        # rotated into the anchor frame (z up)
        C_plane = np.zeros((3, 3))
        C_plane[:2, :2] = cov_u[:2, :2]
        C_plane[2, 2] = bound * bound
        B = self.plane_basis
        C = B @ C_plane @ B.T
        c = np.diag(C)
        return Geometry(
            math.sqrt(float(c.sum())),
            math.sqrt(float(c[0] + c[1])),
            math.sqrt(float(c[2])),
            plane_dop,
            "HDOP (in the anchors' plane)",
            Ju,
        )

    def on_tag_side(self, theta: np.ndarray) -> np.ndarray:
        """Coplanar layouts: reflect theta's position through the anchors' plane when it is on
        the side opposite ``tag_side`` (the ranges cannot tell the two apart)."""
        if self.side_normal is None or not np.all(np.isfinite(theta)):
            return theta
        h = float((theta[:3] - self.plane_point) @ self.side_normal)
        if h >= 0.0:
            return theta
        out = theta.astype(float).copy()
        out[:3] = out[:3] - 2.0 * h * self.side_normal
        return out
