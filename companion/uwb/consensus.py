"""The UWB fit's consistency check and outlier consensus: which anchors to believe.

A fix is consistent when every anchor's residual, studentised by its leverage (the linearised
leave-one-out residual), is below ``residual_threshold_m`` -- plain least-squares residuals hide
an outlier by pulling the fix towards it. If not, and there are at least two redundant anchors, a
RANSAC-like consensus search (hypotheses from the full fit, every leave-one-out fit and every --
or a seeded sample of -- 4-anchor subset) finds the largest agreeing set; it is re-fitted,
agreeing anchors are taken back, and the worst anchor is dropped and the fix re-solved while
still inconsistent. With fewer than two redundant anchors (4 TWR / 5 TDoA anchors) an
inconsistency can be detected but not attributed, so the sample is refused (a :class:`Refusal`,
which the :class:`companion.uwb.multilateration.Multilaterator` reports as a ``UwbRejection``).

Known limit: with the tag low, inside the anchors' height band (below ~1 m for the packaged
layout), vertical geometry is weak and a 1-2 m NLOS error on one anchor can be absorbed by a
different fix that fits every range within the threshold. The EKF's chi-square gate is the
second line of defence there.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from companion.config import MultilaterationConfig  # [landing.multilateration], declared there
from companion.uwb.anchors import MIN_ANCHORS
from companion.uwb.fix_geometry import FixGeometry
from companion.uwb.linalg import inv
from companion.uwb.measurements import MultilaterationCounters, RejectReason
from companion.uwb.models import MeasurementModel, model_residuals
from companion.uwb.solver import levenberg_marquardt, levenberg_marquardt_residuals


@dataclass
class Solution:
    theta: np.ndarray
    cost: float
    residuals: np.ndarray


@dataclass(frozen=True)
class Refusal:
    """Why the anchors gave no consistent fit (the Multilaterator's ``UwbRejection`` of the sample)."""

    reason: RejectReason
    detail: str
    usable: int


class ConsensusFitter:
    """Fits on one layout's anchors, their consistency check and the outlier consensus.

    Owned by a :class:`companion.uwb.multilateration.Multilaterator`, whose ``config``, fix
    geometry and ``counters`` (``outliers_dropped``) it shares. Deterministic: the subset sampling
    uses a numpy Generator seeded with ``config.seed``.
    """

    def __init__(self, config: MultilaterationConfig, geometry: FixGeometry, counters: MultilaterationCounters) -> None:
        self.config = config
        self.geometry = geometry
        self.counters = counters
        self._rng = np.random.default_rng(config.seed)

    def consistent_fit(
        self, anchors: np.ndarray, obs: np.ndarray, model: MeasurementModel, prior: np.ndarray | None
    ) -> tuple[np.ndarray, Solution] | Refusal:
        """The fit on every anchor, or where it is inconsistent the consensus's (kept anchor
        indices, solution); refused when no fit, or no consistent subset, or too few redundant
        anchors to tell which one is wrong."""
        n = len(anchors)
        sol = self.fit(anchors, obs, model, prior)
        if sol is None:
            return Refusal(RejectReason.BAD_GEOMETRY, "degenerate anchor geometry", n)
        if self.consistent(anchors, obs, model, sol)[0]:
            return np.arange(n), sol
        if n - model.n_unknowns < 2:
            thr = self.config.residual_threshold_m
            why = model.inconsistent_detail(n)
            return Refusal(RejectReason.INCONSISTENT, f"residuals exceed {thr} m{why}", n)
        robust = self.consensus(anchors, obs, model, prior)
        if robust is None:
            return Refusal(RejectReason.INCONSISTENT, "no consistent anchor subset", n)
        return robust

    def fit(
        self, anchors: np.ndarray, obs: np.ndarray, model: MeasurementModel, prior: np.ndarray | None
    ) -> Solution | None:
        sols = self.fit_all(anchors, obs, model, prior)
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

    def fit_all(
        self,
        anchors: np.ndarray,
        obs: np.ndarray,
        model: MeasurementModel,
        prior: np.ndarray | None,
        refine: bool = True,
    ) -> list[Solution]:
        cfg = self.config
        geo = self.geometry
        seeds = model.seeds(anchors, obs, prior, geo.side_normal)
        out: list[Solution] = []
        for seed in seeds:
            if not all(map(math.isfinite, seed.tolist())):
                continue
            seed = geo.on_tag_side(seed)
            if refine:
                theta, cost, r0 = levenberg_marquardt_residuals(
                    seed, anchors, obs, model, cfg.max_iterations, cfg.step_tolerance_m
                )
                if geo.side_normal is not None and float((theta[:3] - geo.plane_point) @ geo.side_normal) < 0:
                    # converged to the mirror image: reflect it to the tag's side and refine there
                    theta, cost, r0 = levenberg_marquardt_residuals(
                        geo.on_tag_side(theta), anchors, obs, model, cfg.max_iterations, cfg.step_tolerance_m
                    )
            else:  # an exactly determined closed-form solution (minimal TDoA subset)
                theta = seed
                r0 = model_residuals(seed, anchors, obs, model)
                cost = float(r0 @ r0)
            if not (all(map(math.isfinite, theta.tolist())) and math.isfinite(cost)):
                continue
            if geo.side_normal is not None:
                h = float((theta[:3] - geo.plane_point) @ geo.side_normal)
                if h < -model.in_plane_m:
                    continue  # still on the wrong side: not a solution for this layout
                if h < 0.0:
                    # at the plane the refinement steps across it and back (the height is not
                    # observed there): take its mirror image on the tag's side, which fits the
                    # same for anchors exactly at one height (within a few mm for near-coplanar)
                    theta = geo.on_tag_side(theta)
                    r0 = model_residuals(theta, anchors, obs, model)
                    cost = float(r0 @ r0)
            out.append(Solution(theta, cost, r0))  # r0: model_residuals at theta
        return out

    def consistent(
        self, anchors: np.ndarray, obs: np.ndarray, model: MeasurementModel, sol: Solution
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
        if self.geometry.coplanar and model.plane_gated:
            J = self.geometry.at(sol.theta, anchors, model).jacobian
            cov = inv(J.T.dot(J))
        else:
            J, cov = self.geometry.jacobian_cov(sol.theta, anchors, model)
        if cov is None:  # singular (np.linalg.inv raised)
            return False, score
        h = np.einsum("ij,jk,ik->i", J, cov, J)
        # score_i = |r_i| / sqrt(1 - h_ii) where 1 - h_ii > 1e-6, else |r_i| (on floats: the same
        # IEEE operations as the array form, without its five temporaries)
        scores = [
            a / math.sqrt(1.0 - hi) if 1.0 - hi > 1e-6 else a for a, hi in zip(score.tolist(), h.tolist(), strict=True)
        ]
        thr = self.config.residual_threshold_m
        return all(v <= thr for v in scores), np.array(scores)

    def subsets(self, n: int) -> list[tuple[int, ...]]:
        total = math.comb(n, MIN_ANCHORS)
        if total <= self.config.max_subsets:
            return list(itertools.combinations(range(n), MIN_ANCHORS))
        picked: set[tuple[int, ...]] = set()
        while len(picked) < self.config.max_subsets:
            picked.add(tuple(sorted(self._rng.choice(n, MIN_ANCHORS, replace=False).tolist())))
        return sorted(picked)

    def consensus(
        self, anchors: np.ndarray, obs: np.ndarray, model: MeasurementModel, prior: np.ndarray | None
    ) -> tuple[np.ndarray, Solution] | None:
        """RANSAC-like: every 4-anchor subset proposes fixes; keep the one most anchors agree
        with (MSAC score), re-fit its inliers, then drop the worst anchor while needed."""
        thr = self.config.residual_threshold_m
        n = len(anchors)
        n_unknowns = model.n_unknowns
        cfg = self.config
        best: tuple[int, float, np.ndarray] | None = None
        hypotheses: list[np.ndarray] = []
        full = self.fit(anchors, obs, model, prior)
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
        for subset in self.subsets(n):
            idx = list(subset)
            # hypotheses straight from the closed forms (exact for minimal TDoA subsets); only
            # the winner is refined, which keeps the search ~10x cheaper than refining each
            for s in self.fit_all(anchors[idx], obs[idx], model, prior, refine=False):
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
        sol = self.fit(anchors[keep], obs[keep], model, theta[:3])
        if sol is None:
            return None
        # RANSAC's last step: take back every anchor that agrees with the refined fix
        back = np.flatnonzero(np.abs(model_residuals(sol.theta, anchors, obs, model)) <= thr)
        if len(back) > len(keep):
            again = self.fit(anchors[back], obs[back], model, sol.theta[:3])
            if again is not None:
                keep, sol = back, again
        # drop the worst anchor and re-solve while the set is not consistent
        while True:
            ok, scores = self.consistent(anchors[keep], obs[keep], model, sol)
            if ok:
                break
            if len(keep) - 1 - n_unknowns < 1:
                return None
            keep = np.delete(keep, int(np.argmax(scores)))
            nxt = self.fit(anchors[keep], obs[keep], model, sol.theta[:3])
            if nxt is None:
                return None
            sol = nxt
        self.counters.outliers_dropped += n - len(keep)
        return keep, sol
