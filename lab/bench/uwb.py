"""Micro-benchmark of the UWB multilateration (for ``companion bench uwb``)."""

from __future__ import annotations

import time

import numpy as np

from companion.uwb.anchors import AnchorLayout, load_anchor_layout
from companion.uwb.measurements import TdoaMeasurement, TwrMeasurement
from companion.uwb.multilateration import Multilaterator


def bench_multilateration(n: int = 200, layout: AnchorLayout | None = None) -> dict[str, float]:
    """Microseconds per solve with the packaged layout (6 anchors): TWR and TDoA, clean and with
    one NLOS outlier (the consensus path)."""
    if n < 1:
        raise ValueError("n must be >= 1")
    layout = layout or load_anchor_layout()
    anchors = layout.positions_array()
    ids = layout.anchor_ids
    rng = np.random.default_rng(0)
    p = np.array([0.3, -0.2, 3.0])
    d = np.linalg.norm(anchors - p, axis=1) + rng.normal(0, 0.03, len(ids))
    d_bad = d.copy()
    d_bad[2] += 1.5
    cases = {
        "twr_us": TwrMeasurement(0.0, ids, tuple(d)),
        "twr_outlier_us": TwrMeasurement(0.0, ids, tuple(d_bad)),
        "tdoa_us": TdoaMeasurement(0.0, ids[0], ids[1:], tuple(d[1:] - d[0])),
        "tdoa_outlier_us": TdoaMeasurement(0.0, ids[0], ids[1:], tuple(d_bad[1:] - d_bad[0])),
    }
    out: dict[str, float] = {}
    for name, meas in cases.items():
        m = Multilaterator(layout)
        solve = m.solve_twr if isinstance(meas, TwrMeasurement) else m.solve_tdoa
        t0 = time.perf_counter()
        for _ in range(n):
            solve(meas)  # type: ignore[arg-type]
        out[name] = (time.perf_counter() - t0) / n * 1e6
    return out
