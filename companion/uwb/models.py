"""The UWB measurement models: what two-way ranging and TDoA do differently (delivery eqs 2-4).

One solver, two models (:data:`TWR`, :data:`TDOA`), each giving the residuals, the Jacobian, the
linearised closed-form seeds and the anchor counts the solver needs:

* TWR, ranges d_i: residual r_i = ||x - a_i|| - d_i; seed (:func:`linear_twr_seed`): subtract the
  squared-range equation of a reference anchor from the others -> linear in x.
* TDoA, range differences d_i1 = (t_i - t_1) c to the base anchor (delivery eq 2): written as
  pseudo-ranges rho_i = d_i1 (rho_base = 0) with the unknown base range c = d_1 (delivery eq 4,
  unknown here because the tag's transmit time t_0 is not known): r_i = ||x - a_i|| - c - rho_i.
  Every anchor (the base too) then has one residual, so the base anchor can be judged and dropped
  like any other. Seed (:func:`linear_tdoa_seeds`): delivery eq 3 with the reference anchor moved
  to the origin, (d_i1 + d_1)^2 = K_i - 2 J_i + d_1^2 -> d_i1^2 + 2 d_i1 d_1 = K_i - 2 J_i, linear
  in (x_T, y_T, z_T, d_1); with exactly four anchors the 3x4 system is closed with d_1 = ||x||
  (a quadratic: up to two exact solutions).

Anchors at one height (coplanar layouts): the linear seeds give the tag's position in the anchors'
plane and its distance h from the plane up to sign (TWR: h^2 = d_i^2 - ||x_plane - a_i||^2,
averaged; TDoA: the two roots of delivery eq 3's quadratic are the tag and its mirror image).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from companion.uwb.anchors import MIN_ANCHORS, MIN_COPLANAR_ANCHORS
from companion.uwb.linalg import lstsq, sum_rows

#: coplanar anchors: a refined fix this close to the wrong side of their plane is taken as at the
#: plane (reflected to the tag's side) rather than dropped
_IN_PLANE_M = 0.05


class MeasurementModel(Protocol):
    """What TWR and TDoA do differently; chosen once per measurement (:data:`TWR`, :data:`TDOA`)."""

    name: str
    #: the solution's unknowns: x, y, z (TDoA: and the pseudo-range offset c)
    n_unknowns: int
    #: coplanar anchors: the fix's geometry and leverages taken in (e1, e2, h^2), gated in their plane
    plane_gated: bool
    #: coplanar anchors: a refined fix this far past their plane (m) is taken as at the plane
    in_plane_m: float

    def residuals_of(self, theta: np.ndarray, dist: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """The residuals from the ranges ||x - a_i|| to the anchors (:func:`model_residuals`)."""
        ...

    def jacobian_of(self, diff: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """:func:`model_jacobian` from x - a_i and ||x - a_i|| (the residuals' intermediates)."""
        ...

    def seeds(
        self, anchors: np.ndarray, obs: np.ndarray, prior: np.ndarray | None, side_normal: np.ndarray | None
    ) -> list[np.ndarray]:
        """Starting points: the linearised closed form(s), and the prior (anchor frame) if any."""
        ...

    def min_anchors(self, coplanar: bool) -> int:
        """The fewest anchors a fix needs."""
        ...

    def inconsistent_detail(self, n_anchors: int) -> str:
        """Why an inconsistent fix with fewer than two redundant anchors cannot be repaired."""
        ...

    def subset_hypothesis(self, theta: np.ndarray, anchors: np.ndarray, obs: np.ndarray, idx: list[int]) -> np.ndarray:
        """A subset's closed-form theta made comparable with the other subsets' on all anchors."""
        ...


def _unit_rows(diff: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """d||x - a_i|| / dx: the unit vectors from the anchors to x."""
    return diff / np.maximum(dist, 1e-9)[:, None]


class TwrModel:
    """Two-way ranging: ranges d_i, residual ||x - a_i|| - d_i, unknowns x."""

    name = "TWR"
    n_unknowns = 3
    plane_gated = True
    in_plane_m = _IN_PLANE_M

    def residuals_of(self, theta: np.ndarray, dist: np.ndarray, obs: np.ndarray) -> np.ndarray:
        return dist - obs

    def jacobian_of(self, diff: np.ndarray, dist: np.ndarray) -> np.ndarray:
        return _unit_rows(diff, dist)

    def seeds(
        self, anchors: np.ndarray, obs: np.ndarray, prior: np.ndarray | None, side_normal: np.ndarray | None
    ) -> list[np.ndarray]:
        seeds: list[np.ndarray] = []
        s = linear_twr_seed(anchors, obs, side_normal)
        if s is not None:
            seeds.append(s)
        if prior is not None:
            seeds.append(prior.copy())
        return seeds

    def min_anchors(self, coplanar: bool) -> int:
        """4, or 3 on coplanar anchors with the tag's side known."""
        return MIN_COPLANAR_ANCHORS if coplanar else MIN_ANCHORS

    def inconsistent_detail(self, n_anchors: int) -> str:
        if n_anchors <= self.n_unknowns:  # 3 anchors at one height
            return ": no position fits them (exactly determined: no redundant anchor)"
        return " and too few anchors to tell which one is wrong"

    def subset_hypothesis(self, theta: np.ndarray, anchors: np.ndarray, obs: np.ndarray, idx: list[int]) -> np.ndarray:
        return theta


class TdoaModel:
    """TDoA in pseudo-range form (delivery eqs 2-4): rho_i = d_i1, residual ||x - a_i|| - c - rho_i,
    unknowns x and the offset c."""

    name = "TDoA"
    n_unknowns = 4
    # its pseudo-range offset absorbs a change of height wherever the anchors are about
    # equidistant (near the layout's centre), at any height, not only at their plane
    plane_gated = False
    in_plane_m = 0.0

    def residuals_of(self, theta: np.ndarray, dist: np.ndarray, obs: np.ndarray) -> np.ndarray:
        r = dist - obs
        return r - theta[3]

    def jacobian_of(self, diff: np.ndarray, dist: np.ndarray) -> np.ndarray:
        return np.hstack([_unit_rows(diff, dist), -np.ones((len(diff), 1))])

    def seeds(
        self, anchors: np.ndarray, obs: np.ndarray, prior: np.ndarray | None, side_normal: np.ndarray | None
    ) -> list[np.ndarray]:
        seeds = linear_tdoa_seeds(anchors, obs, ref=0, coplanar=side_normal is not None)
        if prior is not None:
            c = float(np.mean(np.sqrt(np.sum((prior - anchors) ** 2, axis=1)) - obs))
            seeds.append(np.array([prior[0], prior[1], prior[2], c]))
        return seeds

    def min_anchors(self, coplanar: bool) -> int:
        """4 (x, y, z and the offset), coplanar anchors too."""
        return MIN_ANCHORS

    def inconsistent_detail(self, n_anchors: int) -> str:
        return " and too few anchors to tell which one is wrong"

    def subset_hypothesis(self, theta: np.ndarray, anchors: np.ndarray, obs: np.ndarray, idx: list[int]) -> np.ndarray:
        """The offset re-centred on the whole set's median, so that subsets compete fairly."""
        dist = np.sqrt(np.sum((theta[:3] - anchors) ** 2, axis=1))
        theta = theta.copy()
        r_sub = dist[idx] - obs[idx] - theta[3]
        theta[3] += float(np.median(r_sub))
        return theta


TWR: MeasurementModel = TwrModel()
TDOA: MeasurementModel = TdoaModel()


def model_residuals(theta: np.ndarray, anchors: np.ndarray, obs: np.ndarray, model: MeasurementModel) -> np.ndarray:
    """TWR: ||x - a_i|| - d_i.  TDoA (pseudo-range form of eqs 2-4): ||x - a_i|| - c - rho_i."""
    diff = theta[:3] - anchors
    dist = np.sqrt(sum_rows(diff * diff))
    return model.residuals_of(theta, dist, obs)


def model_jacobian(theta: np.ndarray, anchors: np.ndarray, model: MeasurementModel) -> np.ndarray:
    diff = theta[:3] - anchors
    return model.jacobian_of(diff, np.sqrt(sum_rows(diff * diff)))


def linear_twr_seed(
    anchors: np.ndarray, ranges: np.ndarray, side_normal: np.ndarray | None = None
) -> np.ndarray | None:
    """Closed form: ||x||^2 - 2 a_i.x + ||a_i||^2 = d_i^2 minus the same for anchor 0.

    ``side_normal`` (coplanar anchors: the unit normal of their plane towards the tag): the
    linear system only fixes the in-plane position x_p; the distance from the plane is
    h = sqrt(mean(d_i^2 - ||x_p - a_i||^2)) on the side of the normal.
    """
    centre = np.add.reduce(anchors, axis=0) / len(anchors)  # the mean (as anchors.mean(axis=0))
    a = anchors - centre
    k2 = sum_rows(a * a)
    A = 2.0 * (a[1:] - a[0])
    b = (ranges[0] ** 2 - ranges[1:] ** 2) + (k2[1:] - k2[0])
    if side_normal is None:
        sol, rank = lstsq(A, b)
        if rank < 3:
            return None
        return sol + centre
    n = np.asarray(side_normal, dtype=float)
    P = np.eye(3) - np.outer(n, n)  # projector onto the plane
    sol, _, rank, _ = np.linalg.lstsq(A @ P, b, rcond=None)
    if rank < 2:
        return None
    x_p = P @ sol
    h2 = float(np.mean(ranges**2 - np.sum((x_p - a) ** 2, axis=1)))
    return x_p + math.sqrt(max(h2, 0.0)) * n + centre


def linear_tdoa_seeds(anchors: np.ndarray, rho: np.ndarray, ref: int = 0, coplanar: bool = False) -> list[np.ndarray]:
    """Delivery eq 3 with the reference anchor at the origin: unknowns (x', d_ref).

    Returns candidate theta = (x, y, z, c) with c the pseudo-range offset (c = d_ref - rho_ref).
    Four anchors: the 3x4 system plus d_ref = ||x'|| gives up to two exact solutions. Coplanar
    anchors (``coplanar``): the system has rank 3 for any number of anchors, its null vector is
    the plane normal, and the same quadratic gives the tag and its mirror image.
    """
    a = anchors - anchors[ref]
    others = [i for i in range(len(anchors)) if i != ref]
    ai = a[others]
    rik = rho[others] - rho[ref]  # d_i1 relative to the reference (eq 2)
    K = np.sum(ai**2, axis=1)  # K_i
    # d_i1^2 + 2 d_i1 d_1 = K_i - 2 J_i,  J_i = a_i . x   (eq 3, base at the origin)
    M = np.hstack([2.0 * ai, 2.0 * rik[:, None]])
    b = K - rik**2
    thetas: list[np.ndarray] = []
    exact = len(others) < 4 or coplanar
    if not exact:
        sol, _, rank, _ = np.linalg.lstsq(M, b, rcond=None)
        if rank < 4:
            return []
        cands = [sol]
    else:
        U, s, Vt = np.linalg.svd(M, full_matrices=True)
        if len(s) < 3 or s[2] < 1e-9 * max(s[0], 1e-12):
            return []
        p = Vt[:3].T @ ((U.T @ b)[:3] / s[:3])
        q = Vt[3]
        px, pd, qx, qd = p[:3], p[3], q[:3], q[3]
        # (p_d + s q_d)^2 = ||p_x + s q_x||^2  (the constraint d_1 = ||x|| of eq 3 / eq 4)
        A2 = qd * qd - qx @ qx
        B2 = 2.0 * (pd * qd - px @ qx)
        C2 = pd * pd - px @ px
        roots: list[float] = []
        if abs(A2) < 1e-12:
            if abs(B2) > 1e-12:
                roots = [-C2 / B2]
        else:
            disc = B2 * B2 - 4 * A2 * C2
            if disc >= 0.0:
                sq = math.sqrt(disc)
                roots = [(-B2 + sq) / (2 * A2), (-B2 - sq) / (2 * A2)]
            else:  # noise made it slightly complex: take the real part
                roots = [-B2 / (2 * A2)]
        cands = [p + t * q for t in roots]
    if not exact:
        # over-determined: the d_1 estimate of the linear solution is noisy (and can come out
        # negative with an outlier); take only x from it and the offset from x
        x = cands[0][:3] + anchors[ref]
        c_off = float(np.mean(np.sqrt(np.sum((x - anchors) ** 2, axis=1)) - rho))
        return [np.array([x[0], x[1], x[2], c_off])]
    # exactly determined: keep the roots with a non-negative base range d_1 (eq 4)
    valid = [c for c in cands if c[3] >= -1e-6] or cands
    for c in valid:
        x = c[:3] + anchors[ref]
        thetas.append(np.array([x[0], x[1], x[2], c[3] - rho[ref]]))
    return thetas
