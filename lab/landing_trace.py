"""Where a real landing's error is set: the descent traces of ``campaign landing --autopilot``
(``<out>/sitl/landing_traces/*.csv``, firmware/truth_harness.LANDING_TRACE_FIELDS), split into the
companion's control error and its estimation error, at the first ground contact and by height.

    python -m companion_lab.landing_trace runs/real-px4-.../sitl/landing_traces

The first contact is the first tick the truth is at or below the take-off level (SIH's ground):
there the vehicle stops, whereas the autopilot reports ON_GROUND seconds later (PX4 ~3-7 s), by
which time its estimate and the companion's have moved on while the vehicle has not.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

CONTACT_HEIGHT_M = 0.005  # the truth at or below this above the take-off level: on the ground
BANDS_M = ((2.0, 3.0), (1.0, 2.0), (0.5, 1.0), (0.0, 0.5))


class TraceError(ValueError):
    pass


@dataclass(frozen=True)
class Contact:
    """One landing at its first ground contact, cm (north, east)."""

    name: str
    error_cm: float  # truth from the pad
    believed_cm: float  # the companion's estimate from the configured pad (its control error)
    estimate_error_cm: tuple[float, float]  # estimate - truth
    moved_after_cm: float  # how far the truth moved from the contact to the last row (ON_GROUND)
    speed_at_contact_m_s: float  # truth, horizontal, the tick before contact


def read_trace(path: Path) -> dict[str, np.ndarray]:
    try:
        with path.open(newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except OSError as err:
        raise TraceError(f"{path}: {err.strerror}") from None
    if not rows:
        raise TraceError(f"{path}: no rows")
    try:
        return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}
    except (TypeError, ValueError) as err:
        raise TraceError(f"{path}: not a landing trace ({err})") from None


def contact(name: str, tr: dict[str, np.ndarray]) -> Contact | None:
    h = tr["truth_h_m"]
    idx = np.flatnonzero(h <= CONTACT_HEIGHT_M)
    if idx.size == 0:
        return None
    i = int(idx[0])
    tn, te = tr["truth_n_m"], tr["truth_e_m"]
    en, ee = tr["est_n_m"], tr["est_e_m"]
    j = max(i - 1, 0)
    return Contact(
        name,
        100 * math.hypot(tn[i], te[i]),
        100 * math.hypot(en[i], ee[i]),
        (100 * (en[i] - tn[i]), 100 * (ee[i] - te[i])),
        100 * math.hypot(tn[-1] - tn[i], te[-1] - te[i]),
        math.hypot(tr["truth_vn_m_s"][j], tr["truth_ve_m_s"][j]),
    )


def bands(tr: dict[str, np.ndarray]) -> list[tuple[tuple[float, float], int, float, float, float]]:
    """Per height band before the contact: ticks, truth RMS from the pad, estimate RMS from the pad
    (what the control saw), RMS of estimate - truth; cm."""
    h = tr["truth_h_m"]
    idx = np.flatnonzero(h <= CONTACT_HEIGHT_M)
    end = int(idx[0]) if idx.size else h.size
    out = []
    for lo, hi in BANDS_M:
        m = np.zeros(h.size, dtype=bool)
        m[:end] = (h[:end] >= lo) & (h[:end] < hi)
        if not m.any():
            continue
        dn, de = tr["est_n_m"] - tr["truth_n_m"], tr["est_e_m"] - tr["truth_e_m"]
        truth, est, diff = (
            _rms(tr["truth_n_m"], tr["truth_e_m"], m),
            _rms(tr["est_n_m"], tr["est_e_m"], m),
            _rms(dn, de, m),
        )
        out.append(((lo, hi), int(m.sum()), truth, est, diff))
    return out


def _rms(a: np.ndarray, b: np.ndarray, m: np.ndarray) -> float:
    """Horizontal RMS of (a, b) over the rows in m, cm."""
    return float(100 * np.sqrt(np.mean(a[m] ** 2 + b[m] ** 2)))


def report(folder: Path) -> str:
    files = sorted(folder.glob("*.csv"))
    if not files:
        raise TraceError(f"{folder}: no landing traces (*.csv)")
    lines = [
        "landing          at contact: error  believed  est-truth (N, E)   moved after  speed"
        " | by height: truth / est / est-truth RMS cm"
    ]
    contacts = []
    for p in files:
        tr = read_trace(p)
        c = contact(p.stem, tr)
        b = "  ".join(f"{lo:.1f}-{hi:.1f} m {t:4.1f}/{e:4.1f}/{d:4.1f}" for (lo, hi), _, t, e, d in bands(tr))
        if c is None:
            lines.append(f"{p.stem:16s} no ground contact in the trace | {b}")
            continue
        contacts.append(c)
        lines.append(
            f"{c.name:16s} {c.error_cm:6.1f} {c.believed_cm:8.1f}   "
            f"({c.estimate_error_cm[0]:5.1f}, {c.estimate_error_cm[1]:5.1f})  {c.moved_after_cm:9.1f}  "
            f"{c.speed_at_contact_m_s:5.2f} | {b}"
        )
    if contacts:
        en = np.array([c.estimate_error_cm for c in contacts])
        lines.append(
            f"mean over {len(contacts)}: error {np.mean([c.error_cm for c in contacts]):.1f} cm at contact, believed "
            f"{np.mean([c.believed_cm for c in contacts]):.1f} cm, est-truth mean ({en[:, 0].mean():.1f}, "
            f"{en[:, 1].mean():.1f}) cm, moved after contact {np.mean([c.moved_after_cm for c in contacts]):.1f} cm"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m companion_lab.landing_trace", description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path, help="a campaign's sitl/landing_traces folder")
    args = ap.parse_args(argv)
    try:
        print(report(args.folder))
    except TraceError as err:
        print(f"landing_trace: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
