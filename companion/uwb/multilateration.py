"""UWB multilateration: TDoA (delivery eqs 2-4) and two-way ranging (DWM1001 PANS), robust.

:class:`Multilaterator` turns one UWB sample into a :class:`~companion.uwb.measurements.UwbFix`
or a typed :class:`~companion.uwb.measurements.UwbRejection`, never a guess. Its parts:

| module | does |
|---|---|
| ``measurements.py`` | the measurement and result types, ``TdoaMeasurement.from_arrival_times`` (delivery eq 2) |
| ``models.py`` | the TWR and TDoA measurement models (delivery eqs 2-4): residuals, Jacobian, linear seeds (eq 3) |
| ``solver.py`` | Levenberg-Marquardt and the dilutions of precision |
| ``linalg.py`` | numpy.linalg's calls at less overhead (the same floats) |
| ``fix_geometry.py`` | the fix's dilutions, gated; coplanar anchors' plane and the tag's side |
| ``consensus.py`` | the consistency check and the RANSAC-like outlier consensus |

Both problems are solved as nonlinear least squares seeded by a linearised closed-form solution
(:mod:`companion.uwb.models`, :mod:`companion.uwb.solver`).

Robustness (beyond the paper), here: non-finite inputs and unknown anchors are dropped and
counted; TWR ranges beyond the 10 m DWM1001 limit (delivery 4.2.2) are dropped, and after solving
any anchor farther than the limit is dropped and the fix re-solved. Inconsistent anchors are
found and dropped by :mod:`companion.uwb.consensus`; with fewer than two redundant anchors (4 TWR
/ 5 TDoA anchors) an inconsistency can be detected but not attributed, so the sample is refused.
Fewer than 4 usable anchors (3 for TWR on coplanar anchors, below), degenerate geometry or PDOP
above the limit: a typed rejection.

Anchors at one height (coplanar layouts, :attr:`AnchorLayout.coplanar`): the fix reports HDOP and
VDOP and ``vertical_weak``; the EKF then weights the vertical by VDOP instead of the isotropic
PDOP. Such a TWR fix is gated on the dilution in the anchors' plane, not on PDOP
(:mod:`companion.uwb.fix_geometry`); a fix whose horizontal is poor (HDOP above ``max_pdop``) is
still refused.

Four TWR anchors (the paper's set-up) leave one redundant range: an inconsistent range is
detected (the sample is refused) but cannot be attributed to an anchor, so such fixes carry
``outliers_checked = False`` and the first one is logged. With the tag's side known, three
coplanar anchors (a 3-anchor layout, or 3 of a coplanar layout's anchors heard) determine a TWR
fix exactly: ``redundancy = 0``, ``outliers_checked = False``, and nothing is checked beyond a
solution existing (ranges that do not meet on the tag's side within ``residual_threshold_m`` are
refused). Anchors at different heights, and TDoA, still need 4.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike

from companion.config import MultilaterationConfig  # [landing.multilateration], declared there
from companion.uwb.anchors import AnchorLayout
from companion.uwb.consensus import ConsensusFitter, Refusal, Solution
from companion.uwb.fix_geometry import FixGeometry
from companion.uwb.linalg import sum_rows
from companion.uwb.measurements import (
    MultilaterationCounters,
    RejectReason,
    TdoaMeasurement,
    TwrMeasurement,
    UwbFix,
    UwbRejection,
)
from companion.uwb.models import TDOA, TWR, MeasurementModel

log = logging.getLogger(__name__)


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
        self._positions = layout.positions_array()
        self._coplanar = layout.coplanar
        # the fix's dilutions and the anchors' plane; the fits, their consistency and the consensus
        self._geometry = FixGeometry(layout, self.config)
        self._fitter = ConsensusFitter(self.config, self._geometry, self.counters)
        self._logged_unchecked: set[int] = set()
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
        fitted = self._fitter.consistent_fit(anchors, obs, model, prior_arr)
        if isinstance(fitted, Refusal):
            return self._reject(time_s, fitted.reason, fitted.detail, fitted.usable)
        in_range = self._within_range(time_s, anchors, obs, model, *fitted)
        if isinstance(in_range, UwbRejection):
            return in_range
        keep, kept, sol = in_range
        geo = self._geometry.at(sol.theta, kept, model)
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

    def _within_range(
        self,
        time_s: float,
        anchors: np.ndarray,
        obs: np.ndarray,
        model: MeasurementModel,
        keep: np.ndarray,
        sol: Solution,
    ) -> tuple[np.ndarray, np.ndarray, Solution] | UwbRejection:
        """The range limit (delivery 4.2.2): anchors too far from the fix are not trusted; the
        fix re-solved without them. Returns (kept indices, their positions, solution)."""
        kept = anchors if len(keep) == len(anchors) else anchors[keep]  # (all kept: the same values)
        diff = sol.theta[:3] - kept
        dist = np.sqrt(sum_rows(diff * diff))
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
        refit = self._fitter.fit(kept, obs[keep], model, sol.theta[:3])
        if refit is None:
            return self._reject(time_s, RejectReason.BAD_GEOMETRY, "degenerate geometry in range", len(keep))
        if not self._fitter.consistent(kept, obs[keep], model, refit)[0]:
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
