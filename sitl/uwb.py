"""Simulated UWB (Decawave DWM1001-like) source: TWR ranges and TDoA differences from the true
tag position, with Gaussian noise, positive NLOS biases, dropouts and the 10 m range limit
(delivery 4.2.2). Deterministic for a given numpy Generator seed.

The simulated source emits the same messages as the hardware path (``companion.uwb``
``TwrMeasurement`` / ``TdoaMeasurement``) and can also render a DWM1001 ``lec`` CSV line, so
the driver's parser and the multilateration see simulated data exactly as they see the device.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.uwb.anchors import AnchorLayout
from companion.uwb.measurements import TdoaMeasurement, TwrMeasurement

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class UwbSimConfig:
    """Error model, per anchor and sample. Units in the names."""

    range_sigma_m: float = 0.05  # TWR range noise / TDoA per-anchor arrival noise (times c)
    nlos_probability: float = 0.0  # chance that an anchor's path is non-line-of-sight
    nlos_bias_mean_m: float = 0.8  # NLOS excess path length: exponential, always positive
    dropout_probability: float = 0.0  # chance an anchor is missing from a sample
    max_range_m: float | None = None  # None: the layout's (10 m DWM1001)

    def __post_init__(self) -> None:
        for name in ("nlos_probability", "dropout_probability"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"UwbSimConfig.{name} = {v!r}: must be in [0, 1]")
        for name in ("range_sigma_m", "nlos_bias_mean_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"UwbSimConfig.{name} = {v!r}: must be finite and >= 0")
        if self.max_range_m is not None and not (math.isfinite(self.max_range_m) and self.max_range_m > 0):
            raise ValueError(f"UwbSimConfig.max_range_m = {self.max_range_m!r}: must be > 0")


class SimulatedUwb:
    """Ranges and range differences for a tag at a true position in the anchor frame."""

    def __init__(
        self, layout: AnchorLayout, config: UwbSimConfig | None = None, seed: int | np.random.Generator = 0
    ) -> None:
        self.layout = layout
        self.config = config or UwbSimConfig()
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self.max_range_m = self.config.max_range_m if self.config.max_range_m is not None else layout.max_range_m
        self._anchors = layout.positions_array()
        #: ids of anchors that were NLOS / dropped / out of range in the last sample (for tests)
        self.last_nlos_ids: tuple[str, ...] = ()
        self.last_dropped_ids: tuple[str, ...] = ()
        self.last_out_of_range_ids: tuple[str, ...] = ()

    def true_ranges(self, position_m: ArrayLike) -> np.ndarray:
        p = np.asarray(position_m, dtype=float).reshape(3)
        return np.sqrt(np.sum((self._anchors - p) ** 2, axis=1))

    def _sample_errors(self, position_m: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(measured path lengths, visible mask, nlos mask) for every anchor."""
        cfg = self.config
        n = len(self._anchors)
        true = self.true_ranges(position_m)
        noise = self.rng.normal(0.0, cfg.range_sigma_m, n)
        nlos = self.rng.random(n) < cfg.nlos_probability
        bias = np.where(nlos, self.rng.exponential(cfg.nlos_bias_mean_m, n), 0.0) if cfg.nlos_bias_mean_m > 0 else 0.0
        dropped = self.rng.random(n) < cfg.dropout_probability
        in_range = true <= self.max_range_m
        visible = in_range & ~dropped
        ids = self.layout.anchor_ids
        self.last_nlos_ids = tuple(ids[i] for i in range(n) if nlos[i] and visible[i])
        self.last_dropped_ids = tuple(ids[i] for i in range(n) if dropped[i] and in_range[i])
        self.last_out_of_range_ids = tuple(ids[i] for i in range(n) if not in_range[i])
        return true + noise + bias, visible, nlos

    def twr(self, time_s: float, position_m: ArrayLike) -> TwrMeasurement:
        """Two-way ranges to every visible anchor (clipped at zero)."""
        meas, visible, _ = self._sample_errors(position_m)
        ids = self.layout.anchor_ids
        idx = np.flatnonzero(visible)
        return TwrMeasurement(float(time_s), tuple(ids[i] for i in idx), tuple(float(max(0.0, meas[i])) for i in idx))

    def tdoa(self, time_s: float, position_m: ArrayLike) -> TdoaMeasurement | None:
        """Range differences to the base anchor (delivery eq 2); None if the base is not heard."""
        meas, visible, _ = self._sample_errors(position_m)
        ids = self.layout.anchor_ids
        b = self.layout.base_index
        if not visible[b]:
            return None
        others = [i for i in np.flatnonzero(visible) if i != b]
        return TdoaMeasurement(
            float(time_s),
            ids[b],
            tuple(ids[i] for i in others),
            tuple(float(meas[i] - meas[b]) for i in others),
        )


def format_lec_line(
    layout: AnchorLayout,
    measurement: TwrMeasurement,
    position_m: ArrayLike | None = None,
    quality_factor: int = 80,
    max_anchors: int = 4,
) -> str:
    """A DWM1001 PANS ``lec`` CSV line (without line ending) for a TWR measurement.

    ``DIST,<n>,AN0,<id>,<x>,<y>,<z>,<d>,...[,POS,<x>,<y>,<z>,<qf>]``; the device reports at most
    four anchors.
    """
    n = min(max_anchors, len(measurement.anchor_ids))
    parts = ["DIST", str(n)]
    for k in range(n):
        aid = measurement.anchor_ids[k]
        x, y, z = layout.position_of(aid)
        parts += [f"AN{k}", aid, f"{x:.2f}", f"{y:.2f}", f"{z:.2f}", f"{measurement.ranges_m[k]:.2f}"]
    if position_m is not None:
        px, py, pz = np.asarray(position_m, dtype=float).reshape(3)
        parts += ["POS", f"{px:.2f}", f"{py:.2f}", f"{pz:.2f}", str(int(quality_factor))]
    return ",".join(parts)
