"""UWB measurements in, fixes and rejections out: what the multilateration takes and returns.

Two-way ranging (a DWM1001 in PANS mode) reports ranges d_i to the anchors; TDoA reports range
differences d_i1 = (t_i - t_1) c to a base anchor (delivery eq 2). The solver
(:class:`companion.uwb.multilateration.Multilaterator`) answers each sample with a :class:`UwbFix`
or a typed :class:`UwbRejection`, and counts what it dropped in :class:`MultilaterationCounters`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

SPEED_OF_LIGHT_M_S = 299_792_458.0


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
