"""The UWB solver's numerics: Levenberg-Marquardt and the dilutions of precision.

Both problems (TWR and TDoA, :mod:`companion.uwb.models`) are solved as nonlinear least squares
(Levenberg-Marquardt, hand-written: three or four unknowns and a few iterations, so the per-call
overhead of ``scipy.optimize.least_squares`` would dominate) seeded by the models' linearised
closed-form solutions. The dilutions (PDOP, HDOP, VDOP) are those of the linearised problem at
the fix; :class:`companion.uwb.fix_geometry.FixGeometry` gates them (and coplanar anchors).
"""

from __future__ import annotations

import math

import numpy as np

from companion.uwb.linalg import inv, solve, sum_rows
from companion.uwb.models import MeasurementModel, model_jacobian


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
    theta, cost, _ = levenberg_marquardt_residuals(theta0, anchors, obs, model, max_iterations, step_tolerance)
    return theta, cost


def levenberg_marquardt_residuals(
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
        dist = np.sqrt(sum_rows(diff * diff))
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
            solved = solve(M, -g)
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
    cov = inv(J.T.dot(J))
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
    return dilutions_of_cov(inv(J.T.dot(J)))


def dilutions_of_cov(cov: np.ndarray | None) -> tuple[float, float, float]:
    """(PDOP, HDOP, VDOP) from (J^T J)^-1 (None: singular)."""
    if cov is None:
        return math.inf, math.inf, math.inf
    d0, d1, d2 = cov.diagonal()[:3].tolist()
    if not (0.0 < d0 < math.inf and 0.0 < d1 < math.inf and 0.0 < d2 < math.inf):  # finite and > 0
        return math.inf, math.inf, math.inf
    return math.sqrt(d0 + d1 + d2), math.sqrt(d0 + d1), math.sqrt(d2)
