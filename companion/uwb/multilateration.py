"""UWB multilateration: TDoA (delivery eqs 2-4) and two-way ranging (DWM1001 PANS), robust.

Both problems are solved as nonlinear least squares (Levenberg-Marquardt, hand-written: three or
four unknowns and a few iterations, so the per-call overhead of ``scipy.optimize.least_squares``
would dominate) seeded by a linearised closed-form solution:

* TWR, ranges d_i: residual r_i = ||x - a_i|| - d_i; seed: subtract the squared-range equation
  of a reference anchor from the others -> linear in x.
* TDoA, range differences d_i1 = (t_i - t_1) c to the base anchor (delivery eq 2): written as
  pseudo-ranges rho_i = d_i1 (rho_base = 0) with the unknown base range c = d_1 (delivery eq 4,
  unknown here because the tag's transmit time t_0 is not known): r_i = ||x - a_i|| - c - rho_i.
  Every anchor (the base too) then has one residual, so the base anchor can be judged and dropped
  like any other. Seed: delivery eq 3 with the reference anchor moved to the origin,
  (d_i1 + d_1)^2 = K_i - 2 J_i + d_1^2 -> d_i1^2 + 2 d_i1 d_1 = K_i - 2 J_i, linear in
  (x_T, y_T, z_T, d_1); with exactly four anchors the 3x4 system is closed with d_1 = ||x||
  (a quadratic: up to two exact solutions).

Robustness (beyond the paper): non-finite inputs and unknown anchors are dropped and counted;
TWR ranges beyond the 10 m DWM1001 limit (delivery 4.2.2) are dropped, and after solving any
anchor farther than the limit is dropped and the fix re-solved. A fix is consistent when every
anchor's residual, studentised by its leverage (the linearised leave-one-out residual), is
below ``residual_threshold_m`` -- plain least-squares residuals hide an outlier by pulling the
fix towards it. If not, and there are at least two redundant anchors, a RANSAC-like consensus
search (hypotheses from the full fit, every leave-one-out fit and every -- or a seeded sample
of -- 4-anchor subset) finds the largest agreeing set; it is re-fitted, agreeing anchors are
taken back, and the worst anchor is dropped and the fix re-solved while still inconsistent.
With fewer than two redundant anchors (4 TWR / 5 TDoA anchors) an inconsistency can be detected
but not attributed, so the sample is refused. Fewer than 4 usable anchors (3 for TWR on coplanar
anchors, below), degenerate geometry or PDOP above the limit: a typed :class:`UwbRejection`,
never a guess.

Anchors at one height (coplanar layouts, :attr:`AnchorLayout.coplanar`): the linear seeds give
the tag's position in the anchors' plane and its distance h from the plane up to sign (TWR:
h^2 = d_i^2 - ||x_plane - a_i||^2, averaged; TDoA: the two roots of delivery eq 3's quadratic
are the tag and its mirror image); the solution on the layout's ``tag_side`` is kept (a fix that
converged to the mirror side is reflected back and re-refined). The fix reports HDOP and VDOP
and ``vertical_weak``; the EKF then weights the vertical by VDOP instead of the isotropic PDOP.
Such a fix is gated on the dilution in the anchors' plane (HDOP for anchors at one height), not
on PDOP: a tag at (or near) the plane, or ranges slightly too short for any height so that the
fitted height collapses onto the plane, still has a well-determined horizontal. There the
linearised VDOP diverges; the reported VDOP is a second-order bound instead (h enters the ranges
as h^2, see ``Multilaterator._geometry``), so the EKF hardly uses that vertical. A fix whose
horizontal is poor (HDOP above ``max_pdop``) is still refused. This is TWR only: TDoA on coplanar
anchors keeps the PDOP gate (its unknown offset absorbs the height wherever the anchors are about
equidistant, at any height).

Four TWR anchors (the paper's set-up) leave one redundant range: an inconsistent range is
detected (the sample is refused) but cannot be attributed to an anchor, so such fixes carry
``outliers_checked = False`` and the first one is logged. With the tag's side known, three
coplanar anchors (a 3-anchor layout, or 3 of a coplanar layout's anchors heard) determine a TWR
fix exactly: ``redundancy = 0``, ``outliers_checked = False``, and nothing is checked beyond a
solution existing (ranges that do not meet on the tag's side within ``residual_threshold_m`` are
refused). Anchors at different heights, and TDoA, still need 4.

Known limit: with the tag low, inside the anchors' height band (below ~1 m for the packaged
layout), vertical geometry is weak and a 1-2 m NLOS error on one anchor can be absorbed by a
different fix that fits every range within the threshold. The EKF's chi-square gate is the
second line of defence there.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg.lapack import dgelsd as _gelsd
from scipy.linalg.lapack import dgelsd_lwork as _gelsd_lwork
from scipy.linalg.lapack import dgesv as _gesv

from companion.config import MultilaterationConfig  # [landing.multilateration], declared there
from companion.uwb.anchors import MIN_ANCHORS, MIN_COPLANAR_ANCHORS, AnchorLayout

log = logging.getLogger(__name__)

SPEED_OF_LIGHT_M_S = 299_792_458.0
#: coplanar anchors: a refined fix this close to the wrong side of their plane is taken as at the
#: plane (reflected to the tag's side) rather than dropped
_IN_PLANE_M = 0.05


@dataclass(frozen=True)
class TwrMeasurement:
    """Two-way-ranging distances from the tag to anchors (what a DWM1001 in PANS mode reports)."""

    time_s: float
    anchor_ids: tuple[str, ...]
    ranges_m: tuple[float, ...]


@dataclass(frozen=True)
class TdoaMeasurement:
    """Range differences d_i1 = d_i - d_1 to the base anchor (delivery eq 2), one per other anchor."""

    time_s: float
    base_anchor_id: str
    anchor_ids: tuple[str, ...]
    range_differences_m: tuple[float, ...]

    @staticmethod
    def from_arrival_times(time_s: float, base_anchor_id: str, arrival_times_s: Mapping[str, float]) -> TdoaMeasurement:
        """Delivery eq 2: d_i1 = (t_i - t_1) c from the arrival times at each anchor."""
        t1 = arrival_times_s[base_anchor_id]
        ids = tuple(a for a in arrival_times_s if a != base_anchor_id)
        diffs = tuple((arrival_times_s[a] - t1) * SPEED_OF_LIGHT_M_S for a in ids)
        return TdoaMeasurement(time_s, base_anchor_id, ids, diffs)


@dataclass(frozen=True)
class UwbFix:
    """A tag position in the anchor frame ``frame`` (metres) with its quality figures."""

    time_s: float
    x_m: float
    y_m: float
    z_m: float
    pdop: float
    residual_rms_m: float
    anchors_used: tuple[str, ...]
    frame: str
    #: horizontal / vertical dilution of precision in the anchor frame (z up); NaN when unknown
    hdop: float = math.nan
    vdop: float = math.nan
    #: False when too few redundant anchors were left to reject an outlier (4 TWR / 5 TDoA)
    outliers_checked: bool = True
    #: the anchors are coplanar: the vertical is weakly observed (weight it by ``vdop``)
    vertical_weak: bool = False
    #: measurements beyond the unknowns (None: not known, e.g. a replayed fix). 0: exactly
    #: determined (3 TWR anchors at one height, 4 TDoA anchors), nothing is checked beyond a
    #: solution existing; 1 (4 TWR / 5 TDoA anchors): an inconsistent sample is refused, not
    #: repaired; 2 or more: outliers are rejected (``outliers_checked``)
    redundancy: int | None = None

    @property
    def position_m(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.z_m])


class RejectReason(Enum):
    TOO_FEW_ANCHORS = "too_few_anchors"
    NO_BASE_ANCHOR = "no_base_anchor"
    BAD_GEOMETRY = "bad_geometry"
    INCONSISTENT = "inconsistent"


@dataclass(frozen=True)
class UwbRejection:
    """Why no fix was produced for the sample taken at ``time_s``."""

    time_s: float
    reason: RejectReason
    detail: str
    anchors_usable: int


@dataclass
class MultilaterationCounters:
    fixes: int = 0
    nonfinite_inputs: int = 0
    unknown_anchors: int = 0
    out_of_range: int = 0
    outliers_dropped: int = 0
    rejections: dict[str, int] = field(default_factory=lambda: {r.value: 0 for r in RejectReason})


# --------------------------------------------------------------------------------------------
# pure numerical helpers


# Speed: these run a few dozen times per fix on arrays of 4-10 rows, where numpy's per-call
# overhead is most of the cost. The arithmetic is kept as it was (the same reductions and LAPACK
# routines, so the same floats) but called with less overhead: ``np.add.reduce`` is what ``np.sum``
# calls, and LAPACK's gesv / gelsd are called directly (scipy.linalg.lapack), as ``np.linalg.solve``,
# ``inv`` (gesv on the identity) and ``lstsq`` call them after their argument checks.


_EPS = float(np.finfo(float).eps)
_GELSD_SIZES: dict[tuple[int, int], tuple[int, int]] = {}


def _sum_rows(a: np.ndarray) -> np.ndarray:
    """Row sums, as ``np.sum(a, axis=1)`` (the same reduction without its Python wrapper)."""
    return np.add.reduce(a, axis=1)


def _solve(M: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """``np.linalg.solve(M, b)`` (LAPACK gesv, the same floats); None where it raises (singular)."""
    _, _, x, info = _gesv(M, b)
    return x if info == 0 else None


def _inv(M: np.ndarray) -> np.ndarray | None:
    """``np.linalg.inv(M)`` (numpy solves M X = I with gesv: the same floats); None when singular.

    C-ordered like numpy's result (LAPACK returns it in Fortran order): products such as the
    leverages' ``einsum`` sum in an order that follows the memory layout."""
    x = _solve(M, np.eye(M.shape[0]))
    return None if x is None else np.ascontiguousarray(x)


def _lstsq(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, int]:
    """(solution, rank) of ``np.linalg.lstsq(A, b, rcond=None)`` (LAPACK gelsd with numpy's default
    rcond = eps * max(m, n), the same floats)."""
    m, n = A.shape
    rcond = _EPS * max(m, n)
    sizes = _GELSD_SIZES.get((m, n))
    if sizes is None:  # LAPACK's workspace query (the same answer for every call of one shape)
        work, iwork, _ = _gelsd_lwork(m, n, 1, rcond)
        sizes = _GELSD_SIZES[m, n] = (int(work), int(iwork))
    bb = np.zeros(max(m, n))
    bb[:m] = b
    x, _, rank, info = _gelsd(A, bb, sizes[0], sizes[1], rcond)
    if info != 0:
        raise np.linalg.LinAlgError("SVD did not converge in linear least squares")
    return x[:n], int(rank)


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
    dist = np.sqrt(_sum_rows(diff * diff))
    return model.residuals_of(theta, dist, obs)


def model_jacobian(theta: np.ndarray, anchors: np.ndarray, model: MeasurementModel) -> np.ndarray:
    diff = theta[:3] - anchors
    return model.jacobian_of(diff, np.sqrt(_sum_rows(diff * diff)))


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
    k2 = _sum_rows(a * a)
    A = 2.0 * (a[1:] - a[0])
    b = (ranges[0] ** 2 - ranges[1:] ** 2) + (k2[1:] - k2[0])
    if side_normal is None:
        sol, rank = _lstsq(A, b)
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


def levenberg_marquardt(
    theta0: np.ndarray,
    anchors: np.ndarray,
    obs: np.ndarray,
    model: MeasurementModel,
    max_iterations: int = 30,
    step_tolerance: float = 1e-10,
) -> tuple[np.ndarray, float]:
    """Minimise sum r_i^2 from ``theta0`` (Marquardt-scaled damping); returns (theta, cost).

    Stops on a step below ``step_tolerance``, a relative cost decrease below 1e-12, or when
    no damped step lowers the cost any more (converged to rounding).
    """
    theta, cost, _ = _levenberg_marquardt(theta0, anchors, obs, model, max_iterations, step_tolerance)
    return theta, cost


def _levenberg_marquardt(
    theta0: np.ndarray,
    anchors: np.ndarray,
    obs: np.ndarray,
    model: MeasurementModel,
    max_iterations: int,
    step_tolerance: float,
) -> tuple[np.ndarray, float, np.ndarray]:
    """:func:`levenberg_marquardt`, also returning the residuals at the solution. The Jacobian at
    an accepted point is built from the x - a_i and ||x - a_i|| its residuals were computed from
    (as :func:`model_residuals` then :func:`model_jacobian` compute them)."""

    def residuals(th: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # model_residuals
        diff = th[:3] - anchors
        dist = np.sqrt(_sum_rows(diff * diff))
        return model.residuals_of(th, dist, obs), diff, dist

    theta = theta0.astype(float)  # a copy
    r, diff, dist = residuals(theta)
    cost = float(r.dot(r))
    lam = 1e-6
    n = theta.size
    for _ in range(max_iterations):
        J = model.jacobian_of(diff, dist)
        A = J.T.dot(J)  # J^T J (Gauss-Newton normal matrix)
        g = J.T.dot(r)
        accepted = False
        step = np.zeros(n)
        for _try in range(8):
            M = A.copy()
            Md = M.reshape(-1)[:: n + 1]  # a view of the diagonal: (J^T J + lam diag(J^T J)) + 1e-12 I
            Md *= 1.0 + lam
            Md += 1e-12
            solved = _solve(M, -g)
            if solved is None:  # singular (np.linalg.solve raised)
                lam *= 10.0
                continue
            step = solved
            cand = theta + step
            r_new, diff_new, dist_new = residuals(cand)
            c_new = float(r_new.dot(r_new))
            if c_new <= cost:
                decrease = cost - c_new
                theta, r, cost, diff, dist = cand, r_new, c_new, diff_new, dist_new
                lam = max(lam * 0.1, 1e-12)
                accepted = True
                break
            lam *= 10.0
        # (an accepted step is finite, so the largest |step| on floats equals np.max(np.abs(step)))
        if not accepted or max(map(abs, step.tolist())) < step_tolerance or cost < 1e-26 or decrease <= 1e-12 * cost:
            break
    return theta, cost, r


def dilution_of_precision(theta: np.ndarray, anchors: np.ndarray, model: MeasurementModel) -> float:
    """PDOP = sqrt(trace of the position block of (J^T J)^-1), J the range Jacobian at the fix.

    For TDoA the pseudo-range offset is the fourth unknown (as the clock in GNSS), so this is
    the PDOP of independent per-anchor timing errors, in units of that range error.
    """
    J = model_jacobian(theta, anchors, model)
    cov = _inv(J.T.dot(J))
    if cov is None:  # singular
        return math.inf
    tr = float(np.trace(cov[:3, :3]))
    return math.sqrt(tr) if tr > 0 and math.isfinite(tr) else math.inf


def dilutions_of_precision(
    theta: np.ndarray, anchors: np.ndarray, model: MeasurementModel
) -> tuple[float, float, float]:
    """(PDOP, HDOP, VDOP) from the position block of (J^T J)^-1 (see :func:`dilution_of_precision`):
    HDOP = sqrt(var_x + var_y), VDOP = sqrt(var_z) in the anchor frame (z up), per unit range error."""
    J = model_jacobian(theta, anchors, model)
    return _dilutions_of_cov(_inv(J.T.dot(J)))


def _dilutions_of_cov(cov: np.ndarray | None) -> tuple[float, float, float]:
    """(PDOP, HDOP, VDOP) from (J^T J)^-1 (None: singular)."""
    if cov is None:
        return math.inf, math.inf, math.inf
    d0, d1, d2 = cov.diagonal()[:3].tolist()
    if not (0.0 < d0 < math.inf and 0.0 < d1 < math.inf and 0.0 < d2 < math.inf):  # finite and > 0
        return math.inf, math.inf, math.inf
    return math.sqrt(d0 + d1 + d2), math.sqrt(d0 + d1), math.sqrt(d2)


# --------------------------------------------------------------------------------------------


@dataclass
class _Solution:
    theta: np.ndarray
    cost: float
    residuals: np.ndarray


@dataclass(frozen=True)
class _Geometry:
    """Dilutions of a fix (anchor frame) and the Jacobian its consistency check uses."""

    pdop: float
    hdop: float
    vdop: float
    #: the gated figure: PDOP, or for coplanar anchors the dilution in their plane
    gate_dop: float
    gate_name: str
    jacobian: np.ndarray


class Multilaterator:
    """Robust TWR and TDoA multilateration for one :class:`AnchorLayout`.

    Synchronous and deterministic (subset sampling uses a seeded numpy Generator). Counters in
    ``counters``.
    """

    def __init__(self, layout: AnchorLayout, config: MultilaterationConfig | None = None) -> None:
        self.layout = layout
        self.config = config or MultilaterationConfig()
        self.max_range_m = self.config.max_range_m if self.config.max_range_m is not None else layout.max_range_m
        self.counters = MultilaterationCounters()
        self._rng = np.random.default_rng(self.config.seed)
        self._positions = layout.positions_array()
        self._coplanar = layout.coplanar
        self._side_normal = layout.tag_side_normal if self._coplanar else None
        self._plane_point = layout.plane_point_m
        self._plane_basis: np.ndarray | None = None
        if self._side_normal is not None:
            n = self._side_normal
            e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
            if np.linalg.norm(e1) < 0.5:
                e1 = np.array([0.0, 1.0, 0.0]) - n[1] * n
            e1 = e1 / np.linalg.norm(e1)
            self._plane_basis = np.column_stack([e1, np.cross(n, e1), n])  # in-plane e1, e2; normal
        self._logged_unchecked: set[int] = set()
        # the last (J, (J^T J)^-1) at a fix: the consistency check and the dilutions of one fix
        # need the same pair (keyed by the fix, the anchors and the model)
        self._jc_key: tuple[bytes, bytes, str] | None = None
        self._jc: tuple[np.ndarray, np.ndarray | None] = (np.zeros((0, 3)), None)
        self._index = {a: i for i, a in enumerate(layout.anchor_ids)}  # layout.index_of, as a dict
        if self._coplanar:
            log.info(
                "uwb: anchors of layout %r are coplanar: fixes are taken %s their plane, the vertical is weakly "
                "observed (VDOP reported)",
                layout.frame,
                layout.tag_side,
            )

    # public API ---------------------------------------------------------------------------

    def solve_twr(self, m: TwrMeasurement, prior_m: ArrayLike | None = None) -> UwbFix | UwbRejection:
        """A fix from two-way-ranging distances; ``prior_m`` (anchor frame) helps pick a solution."""
        ids: list[str] = []
        ranges: list[float] = []
        for aid, d in zip(m.anchor_ids, m.ranges_m, strict=True):
            if not _finite(d):
                self.counters.nonfinite_inputs += 1
                continue
            if aid not in self.layout:
                self.counters.unknown_anchors += 1
                continue
            if d < 0.0 or d > self.max_range_m:
                self.counters.out_of_range += 1
                continue
            if aid in ids:  # a duplicate report: keep the first
                continue
            ids.append(aid)
            ranges.append(float(d))
        return self._solve(m.time_s, ids, np.array(ranges), TWR, prior=prior_m)

    def solve_tdoa(self, m: TdoaMeasurement, prior_m: ArrayLike | None = None) -> UwbFix | UwbRejection:
        """A fix from range differences to the base anchor (delivery eqs 2-4)."""
        if m.base_anchor_id not in self.layout:
            self.counters.unknown_anchors += 1
            return self._reject(m.time_s, RejectReason.NO_BASE_ANCHOR, f"base {m.base_anchor_id!r} unknown", 0)
        ids = [m.base_anchor_id]
        rho = [0.0]
        for aid, d in zip(m.anchor_ids, m.range_differences_m, strict=True):
            if not _finite(d):
                self.counters.nonfinite_inputs += 1
                continue
            if aid not in self.layout:
                self.counters.unknown_anchors += 1
                continue
            # |d_i - d_1| <= ||a_i - a_1|| (triangle inequality) and both ranges <= the limit
            if abs(d) > self.max_range_m:
                self.counters.out_of_range += 1
                continue
            if aid in ids:
                continue
            ids.append(aid)
            rho.append(float(d))
        return self._solve(m.time_s, ids, np.array(rho), TDOA, prior=prior_m)

    # internals ----------------------------------------------------------------------------

    def _jacobian_cov(
        self, theta: np.ndarray, anchors: np.ndarray, model: MeasurementModel
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """J = :func:`model_jacobian` at ``theta`` and (J^T J)^-1 (None if singular), computed once
        per fix (the same floats each time, so reusing them changes nothing)."""
        key = (theta.tobytes(), anchors.tobytes(), model.name)
        if key != self._jc_key:
            J = model_jacobian(theta, anchors, model)
            self._jc = (J, _inv(J.T.dot(J)))
            self._jc_key = key
        return self._jc

    def _reject(self, time_s: float, reason: RejectReason, detail: str, usable: int) -> UwbRejection:
        self.counters.rejections[reason.value] += 1
        log.debug("uwb fix rejected at %.3f: %s (%s)", time_s, reason.value, detail)
        return UwbRejection(time_s, reason, detail, usable)

    def _solve(
        self, time_s: float, ids: list[str], obs: np.ndarray, model: MeasurementModel, prior: ArrayLike | None
    ) -> UwbFix | UwbRejection:
        cfg = self.config
        min_anchors = model.min_anchors(self._coplanar)
        if len(ids) < min_anchors:
            return self._reject(
                time_s, RejectReason.TOO_FEW_ANCHORS, f"{len(ids)} usable anchors, need {min_anchors}", len(ids)
            )
        prior_arr = None
        if prior is not None:
            p = np.asarray(prior, dtype=float).reshape(3)
            prior_arr = p if np.all(np.isfinite(p)) else None
        anchors = self._positions[[self._index[a] for a in ids]]
        fitted = self._consistent_fit(time_s, anchors, obs, model, prior_arr)
        if isinstance(fitted, UwbRejection):
            return fitted
        in_range = self._within_range(time_s, anchors, obs, model, *fitted)
        if isinstance(in_range, UwbRejection):
            return in_range
        keep, kept, sol = in_range
        geo = self._geometry(sol.theta, kept, model)
        if not geo.gate_dop <= cfg.max_pdop:
            return self._reject(
                time_s, RejectReason.BAD_GEOMETRY, f"{geo.gate_name} {geo.gate_dop:.1f} > {cfg.max_pdop}", len(keep)
            )
        self.counters.fixes += 1
        redundancy = len(keep) - model.n_unknowns
        checked = redundancy >= 2
        if not checked and redundancy not in self._logged_unchecked:
            self._logged_unchecked.add(redundancy)
            self._log_unchecked(len(keep), redundancy, model)
        res = sol.residuals
        rms = math.sqrt(float(np.add.reduce(res * res)) / len(res))  # as np.sqrt(np.mean(r**2))
        x = sol.theta
        return UwbFix(
            time_s,
            float(x[0]),
            float(x[1]),
            float(x[2]),
            geo.pdop,
            rms,
            tuple(ids[i] for i in keep),
            self.layout.frame,
            geo.hdop,
            geo.vdop,
            checked,
            self._coplanar,
            redundancy,
        )

    def _consistent_fit(
        self, time_s: float, anchors: np.ndarray, obs: np.ndarray, model: MeasurementModel, prior: np.ndarray | None
    ) -> tuple[np.ndarray, _Solution] | UwbRejection:
        """The fit on every anchor, or where it is inconsistent the consensus's (kept anchor
        indices, solution); refused when no fit, or no consistent subset, or too few redundant
        anchors to tell which one is wrong."""
        n = len(anchors)
        sol = self._fit(anchors, obs, model, prior)
        if sol is None:
            return self._reject(time_s, RejectReason.BAD_GEOMETRY, "degenerate anchor geometry", n)
        if self._consistent(anchors, obs, model, sol)[0]:
            return np.arange(n), sol
        if n - model.n_unknowns < 2:
            thr = self.config.residual_threshold_m
            why = model.inconsistent_detail(n)
            return self._reject(time_s, RejectReason.INCONSISTENT, f"residuals exceed {thr} m{why}", n)
        robust = self._consensus(anchors, obs, model, prior)
        if robust is None:
            return self._reject(time_s, RejectReason.INCONSISTENT, "no consistent anchor subset", n)
        return robust

    def _within_range(
        self,
        time_s: float,
        anchors: np.ndarray,
        obs: np.ndarray,
        model: MeasurementModel,
        keep: np.ndarray,
        sol: _Solution,
    ) -> tuple[np.ndarray, np.ndarray, _Solution] | UwbRejection:
        """The range limit (delivery 4.2.2): anchors too far from the fix are not trusted; the
        fix re-solved without them. Returns (kept indices, their positions, solution)."""
        kept = anchors if len(keep) == len(anchors) else anchors[keep]  # (all kept: the same values)
        diff = sol.theta[:3] - kept
        dist = np.sqrt(_sum_rows(diff * diff))
        far = dist > self.max_range_m
        if not far.any():
            return keep, kept, sol
        self.counters.out_of_range += int(np.sum(far))
        keep = keep[~far]
        kept = anchors[keep]
        if len(keep) < model.min_anchors(self._coplanar):
            return self._reject(
                time_s, RejectReason.TOO_FEW_ANCHORS, f"{len(keep)} anchors within {self.max_range_m} m", len(keep)
            )
        refit = self._fit(kept, obs[keep], model, sol.theta[:3])
        if refit is None:
            return self._reject(time_s, RejectReason.BAD_GEOMETRY, "degenerate geometry in range", len(keep))
        if not self._consistent(kept, obs[keep], model, refit)[0]:
            return self._reject(time_s, RejectReason.INCONSISTENT, "inconsistent after range limit", len(keep))
        return keep, kept, refit

    def _log_unchecked(self, n_anchors: int, redundancy: int, model: MeasurementModel) -> None:
        """Said once per redundancy: fixes with fewer than two redundant anchors go unchecked."""
        if redundancy <= 0:
            log.info(
                "uwb: %d %s anchors determine the fix exactly: no redundant measurement, fixes are accepted "
                "without any consistency or outlier check",
                n_anchors,
                model.name,
            )
        else:
            log.info(
                "uwb: %d %s anchors leave one redundant measurement: fixes are accepted without outlier "
                "rejection (an inconsistent sample is refused, not repaired), as in delivery 4.2.2",
                n_anchors,
                model.name,
            )

    def _plane_jacobian(self, theta: np.ndarray, anchors: np.ndarray) -> np.ndarray:
        """Coplanar anchors, TWR: the Jacobian in (e1, e2, u), e1/e2 spanning the anchors' plane and
        u = h^2 the squared distance from it, with the anchors projected onto the plane.

        d_i = sqrt(rho_i^2 + u) has dd_i/du = 1/(2 d_i), finite at h = 0, where the z column of
        the usual Jacobian vanishes; for h > 0 this is a reparametrisation of the third
        coordinate, so the in-plane block of the covariance and the leverages are unchanged.
        """
        assert self._plane_basis is not None
        B = self._plane_basis
        n = B[:, 2]
        x = theta[:3]
        h = float((x - self._plane_point) @ n)
        q = (x - anchors) - np.outer((x - anchors) @ n, n)  # in-plane offsets to the projected anchors
        d = np.maximum(np.sqrt(np.sum(q**2, axis=1) + h * h), 1e-9)
        return np.column_stack([(q @ B[:, 0]) / d, (q @ B[:, 1]) / d, 0.5 / d])

    def _geometry(self, theta: np.ndarray, anchors: np.ndarray, model: MeasurementModel) -> _Geometry:
        """The fix's dilutions. Anchors at different heights: PDOP/HDOP/VDOP of the linearised
        problem, gated on PDOP (unchanged; TDoA too). Coplanar anchors, TWR: gated on the dilution
        in their plane (HDOP for anchors at one height); the vertical is weak by design and
        reported by VDOP.

        At the anchors' plane (h -> 0) the linearised VDOP diverges although the horizontal is
        well determined: h enters the ranges only as u = h^2, whose standard deviation is
        sigma_u = sigma_r sqrt(var_u) (``_plane_jacobian``); a range error of sigma_r therefore
        moves the height by about sqrt(sigma_u) -- a distance that does not vanish at the plane.
        The reported VDOP is the smaller of the linearised one and this second-order bound
        sqrt(sigma_u)/sigma_r = sqrt(sqrt(var_u)/sigma_r) (sigma_r: ``range_sigma_m``). Away from
        the plane the linearised figure is the smaller one and is kept bit for bit.
        """
        J, cov = self._jacobian_cov(theta, anchors, model)
        pdop, hdop, vdop = _dilutions_of_cov(cov)  # dilutions_of_precision(theta, anchors, model)
        if not (self._coplanar and model.plane_gated):  # (TDoA on coplanar anchors: MeasurementModel)
            return _Geometry(pdop, hdop, vdop, pdop, "PDOP", J)
        assert self._plane_basis is not None
        Ju = self._plane_jacobian(theta, anchors)
        try:
            cov_u = np.linalg.inv(Ju.T @ Ju)
        except np.linalg.LinAlgError:
            inf = math.inf
            return _Geometry(inf, inf, inf, inf, "HDOP (in the anchors' plane)", Ju)
        d = np.diag(cov_u)
        if not (np.all(np.isfinite(d[:3])) and np.all(d[:3] > 0.0)):
            inf = math.inf
            return _Geometry(inf, inf, inf, inf, "HDOP (in the anchors' plane)", Ju)
        plane_dop = math.sqrt(float(d[0] + d[1]))
        bound = math.sqrt(math.sqrt(float(d[2])) / self.config.range_sigma_m)
        if vdop <= bound:  # the linearisation holds: the figures as they always were
            return _Geometry(pdop, hdop, vdop, plane_dop, "HDOP (in the anchors' plane)", J)
        # at the plane: the in-plane block from (e1, e2, u), the normal direction from the bound,
        # rotated into the anchor frame (z up)
        C_plane = np.zeros((3, 3))
        C_plane[:2, :2] = cov_u[:2, :2]
        C_plane[2, 2] = bound * bound
        B = self._plane_basis
        C = B @ C_plane @ B.T
        c = np.diag(C)
        return _Geometry(
            math.sqrt(float(c.sum())),
            math.sqrt(float(c[0] + c[1])),
            math.sqrt(float(c[2])),
            plane_dop,
            "HDOP (in the anchors' plane)",
            Ju,
        )

    def _fit(
        self, anchors: np.ndarray, obs: np.ndarray, model: MeasurementModel, prior: np.ndarray | None
    ) -> _Solution | None:
        sols = self._fit_all(anchors, obs, model, prior)
        if not sols:
            return None
        best_cost = min(s.cost for s in sols)
        near = [s for s in sols if s.cost <= best_cost + 1e-6]
        if len(near) > 1:
            if prior is not None:
                return min(near, key=lambda s: float(np.sum((s.theta[:3] - prior) ** 2)))
            if self.config.prefer_high_solution:
                return max(near, key=lambda s: float(s.theta[2]))
        return min(sols, key=lambda s: s.cost)

    def _fit_all(
        self,
        anchors: np.ndarray,
        obs: np.ndarray,
        model: MeasurementModel,
        prior: np.ndarray | None,
        refine: bool = True,
    ) -> list[_Solution]:
        cfg = self.config
        seeds = model.seeds(anchors, obs, prior, self._side_normal)
        out: list[_Solution] = []
        for seed in seeds:
            if not all(map(math.isfinite, seed.tolist())):
                continue
            seed = self._on_tag_side(seed)
            if refine:
                theta, cost, r0 = _levenberg_marquardt(
                    seed, anchors, obs, model, cfg.max_iterations, cfg.step_tolerance_m
                )
                if self._side_normal is not None and float((theta[:3] - self._plane_point) @ self._side_normal) < 0:
                    # converged to the mirror image: reflect it to the tag's side and refine there
                    theta, cost, r0 = _levenberg_marquardt(
                        self._on_tag_side(theta), anchors, obs, model, cfg.max_iterations, cfg.step_tolerance_m
                    )
            else:  # an exactly determined closed-form solution (minimal TDoA subset)
                theta = seed
                r0 = model_residuals(seed, anchors, obs, model)
                cost = float(r0 @ r0)
            if not (all(map(math.isfinite, theta.tolist())) and math.isfinite(cost)):
                continue
            if self._side_normal is not None:
                h = float((theta[:3] - self._plane_point) @ self._side_normal)
                if h < -model.in_plane_m:
                    continue  # still on the wrong side: not a solution for this layout
                if h < 0.0:
                    # at the plane the refinement steps across it and back (the height is not
                    # observed there): take its mirror image on the tag's side, which fits the
                    # same for anchors exactly at one height (within a few mm for near-coplanar)
                    theta = self._on_tag_side(theta)
                    r0 = model_residuals(theta, anchors, obs, model)
                    cost = float(r0 @ r0)
            out.append(_Solution(theta, cost, r0))  # r0: model_residuals at theta
        return out

    def _on_tag_side(self, theta: np.ndarray) -> np.ndarray:
        """Coplanar layouts: reflect theta's position through the anchors' plane when it is on
        the side opposite ``tag_side`` (the ranges cannot tell the two apart)."""
        if self._side_normal is None or not np.all(np.isfinite(theta)):
            return theta
        h = float((theta[:3] - self._plane_point) @ self._side_normal)
        if h >= 0.0:
            return theta
        out = theta.astype(float).copy()
        out[:3] = out[:3] - 2.0 * h * self._side_normal
        return out

    def _consistent(
        self, anchors: np.ndarray, obs: np.ndarray, model: MeasurementModel, sol: _Solution
    ) -> tuple[bool, np.ndarray]:
        """Are all anchors consistent with the fix? Returns (ok, per-anchor score in metres).

        An outlier pulls a least-squares fit towards itself and hides in small residuals, so
        each residual is studentised by its leverage h_ii (the diagonal of the hat matrix
        J (J^T J)^-1 J^T): score_i = |r_i| / sqrt(1 - h_ii), the linearised leave-one-out
        (deleted) residual scaled to the noise level. Anchors without redundancy (h_ii ~ 1)
        are judged by their plain residual.
        """
        score = np.abs(sol.residuals)
        # coplanar anchors with the tag at their plane: the (e1, e2, h^2) Jacobian, whose leverages
        # equal the usual ones away from the plane and stay defined at it
        if self._coplanar and model.plane_gated:
            J = self._geometry(sol.theta, anchors, model).jacobian
            inv = _inv(J.T.dot(J))
        else:
            J, inv = self._jacobian_cov(sol.theta, anchors, model)
        if inv is None:  # singular (np.linalg.inv raised)
            return False, score
        h = np.einsum("ij,jk,ik->i", J, inv, J)
        # score_i = |r_i| / sqrt(1 - h_ii) where 1 - h_ii > 1e-6, else |r_i| (on floats: the same
        # IEEE operations as the array form, without its five temporaries)
        scores = [
            a / math.sqrt(1.0 - hi) if 1.0 - hi > 1e-6 else a for a, hi in zip(score.tolist(), h.tolist(), strict=True)
        ]
        thr = self.config.residual_threshold_m
        return all(v <= thr for v in scores), np.array(scores)

    def _subsets(self, n: int) -> list[tuple[int, ...]]:
        total = math.comb(n, MIN_ANCHORS)
        if total <= self.config.max_subsets:
            return list(itertools.combinations(range(n), MIN_ANCHORS))
        picked: set[tuple[int, ...]] = set()
        while len(picked) < self.config.max_subsets:
            picked.add(tuple(sorted(self._rng.choice(n, MIN_ANCHORS, replace=False).tolist())))
        return sorted(picked)

    def _consensus(
        self, anchors: np.ndarray, obs: np.ndarray, model: MeasurementModel, prior: np.ndarray | None
    ) -> tuple[np.ndarray, _Solution] | None:
        """RANSAC-like: every 4-anchor subset proposes fixes; keep the one most anchors agree
        with (MSAC score), re-fit its inliers, then drop the worst anchor while needed."""
        thr = self.config.residual_threshold_m
        n = len(anchors)
        n_unknowns = model.n_unknowns
        cfg = self.config
        best: tuple[int, float, np.ndarray] | None = None
        hypotheses: list[np.ndarray] = []
        full = self._fit(anchors, obs, model, prior)
        if full is not None:
            hypotheses.append(full.theta)
            for i in range(n):  # leave-one-out fits, started at the full fit
                mask = np.arange(n) != i
                theta, _ = levenberg_marquardt(full.theta, anchors[mask], obs[mask], model, 3, cfg.step_tolerance_m)
                hypotheses.append(theta)
        for theta in hypotheses:
            r_all = model_residuals(theta, anchors, obs, model)
            cnt = int(np.sum(np.abs(r_all) <= thr))
            score = float(np.sum(np.minimum(r_all**2, thr * thr)))
            if best is None or cnt > best[0] or (cnt == best[0] and score < best[1]):
                best = (cnt, score, theta)
        for subset in self._subsets(n):
            idx = list(subset)
            # hypotheses straight from the closed forms (exact for minimal TDoA subsets); only
            # the winner is refined, which keeps the search ~10x cheaper than refining each
            for s in self._fit_all(anchors[idx], obs[idx], model, prior, refine=False):
                theta = model.subset_hypothesis(s.theta, anchors, obs, idx)
                r_all = model_residuals(theta, anchors, obs, model)
                inl = np.abs(r_all) <= thr
                score = float(np.sum(np.minimum(r_all**2, thr * thr)))
                cnt = int(np.sum(inl))
                if best is None or cnt > best[0] or (cnt == best[0] and score < best[1]):
                    best = (cnt, score, theta)
        if best is None or best[0] < MIN_ANCHORS:
            return None
        theta = best[2]
        keep = np.flatnonzero(np.abs(model_residuals(theta, anchors, obs, model)) <= thr)
        sol = self._fit(anchors[keep], obs[keep], model, theta[:3])
        if sol is None:
            return None
        # RANSAC's last step: take back every anchor that agrees with the refined fix
        back = np.flatnonzero(np.abs(model_residuals(sol.theta, anchors, obs, model)) <= thr)
        if len(back) > len(keep):
            again = self._fit(anchors[back], obs[back], model, sol.theta[:3])
            if again is not None:
                keep, sol = back, again
        # drop the worst anchor and re-solve while the set is not consistent
        while True:
            ok, scores = self._consistent(anchors[keep], obs[keep], model, sol)
            if ok:
                break
            if len(keep) - 1 - n_unknowns < 1:
                return None
            keep = np.delete(keep, int(np.argmax(scores)))
            nxt = self._fit(anchors[keep], obs[keep], model, sol.theta[:3])
            if nxt is None:
                return None
            sol = nxt
        self.counters.outliers_dropped += n - len(keep)
        return keep, sol


def _finite(v: object) -> bool:
    try:
        return math.isfinite(float(v))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False


def solve_twr(
    layout: AnchorLayout, time_s: float, ranges_m: Mapping[str, float], config: MultilaterationConfig | None = None
) -> UwbFix | UwbRejection:
    """One-shot TWR solve (a fresh :class:`Multilaterator`; keep one for counters)."""
    ids = tuple(ranges_m)
    return Multilaterator(layout, config).solve_twr(TwrMeasurement(time_s, ids, tuple(ranges_m[a] for a in ids)))


def solve_tdoa(
    layout: AnchorLayout,
    time_s: float,
    range_differences_m: Mapping[str, float],
    base_anchor_id: str | None = None,
    config: MultilaterationConfig | None = None,
) -> UwbFix | UwbRejection:
    """One-shot TDoA solve; ``range_differences_m`` maps anchor id -> d_i1 (delivery eq 2)."""
    base = base_anchor_id or layout.base_anchor_id
    ids = tuple(a for a in range_differences_m if a != base)
    m = TdoaMeasurement(time_s, base, ids, tuple(range_differences_m[a] for a in ids))
    return Multilaterator(layout, config).solve_tdoa(m)
