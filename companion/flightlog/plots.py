"""PNG plots of a run, like the delivery paper's figures (matplotlib, headless Agg backend).

``path_figure`` and ``lyapunov_figure`` build the figures (tests read their artists);
``plot_run`` writes them as path.png and lyapunov.png.
"""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from companion.flightlog.reader import read_columns
from companion.geometry.mission_frame import MissionFrame
from companion.guidance.path import DeliveryPath
from companion.units import format_m

#: Phases in which the vector field is followed (V exists); the others are shaded in lyapunov.png.
FIELD_PHASES = ("outbound", "inbound")

CONFIGURED_PAD_LABEL = "configured pad"
NO_FIELD_LABEL = "no vector field (take-off, landing, release)"
TRUE_PAD_LABEL = "true pad"
TRUE_PAD_PATH_LABEL = "path to the true pad"


def _floats(col: list[str]) -> np.ndarray:
    return np.array([float(v) if v not in ("", "nan") else math.nan for v in col])


def _summary(run: Path) -> dict[str, Any]:
    summary: dict[str, Any] = json.loads((run / "summary.json").read_text())
    if not summary.get("path"):
        raise ValueError(f"{run / 'summary.json'}: no planned path recorded (the mission never planned one)")
    return summary


def _reference_in_planned_frame(summary: dict[str, Any], z_start: float) -> np.ndarray | None:
    """The path from home to the true pad, sampled, in the planned F_I (None if not recorded)."""
    ref, p = summary.get("reference_path"), summary["path"]
    if not ref or "pad_ned_m" not in p:
        return None
    planned = MissionFrame(np.asarray(p["pad_ned_m"], dtype=float), float(p["heading_rad"]))
    ref_frame = MissionFrame(np.asarray(ref["pad_ned_m"], dtype=float), float(ref["heading_rad"]))
    pts = DeliveryPath(p["h_m"], p["r_m"], ref["d_m"]).sample(0.25, z_start=z_start)
    return np.array([planned.point_from_ned(ref_frame.point_to_ned(q)) for q in pts])


def _pads(summary: dict[str, Any]) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Configured pad, true pad and true touchdown on the pad, in the planned F_I (x, y)."""
    configured = np.zeros(2)
    tp = summary.get("true_pad_mission_m")
    true_pad = np.asarray(tp[:2], dtype=float) if tp else None
    touchdown = None
    ne = summary.get("pad_landing_error_ne_m")
    if true_pad is not None and ne and all(v is not None and math.isfinite(v) for v in ne):
        rot = MissionFrame(np.zeros(3), float(summary["path"]["heading_rad"]))
        touchdown = true_pad + rot.vector_from_ned([ne[0], ne[1], 0.0])[:2]
    return configured, true_pad, touchdown


def _estimate_in_outbound_frame(p: dict[str, Any], flight: dict[str, list[str]]) -> tuple[np.ndarray, np.ndarray]:
    """The estimate's x and z in the outbound F_I. flight.csv's mission columns are in the
    mission's frame of the moment, which the way home re-plans; the NED estimate is not."""
    if "pad_ned_m" not in p or "est_north_m" not in flight:
        return _floats(flight["mission_x_m"]), _floats(flight["mission_z_m"])
    frame = MissionFrame(np.asarray(p["pad_ned_m"], dtype=float), float(p["heading_rad"]))
    ned = np.column_stack([_floats(flight[k]) for k in ("est_north_m", "est_east_m", "est_down_m")])
    pts = (frame.R_ned_mission.T @ (ned - frame.pad_ned).T).T
    return pts[:, 0], pts[:, 2]


def path_figure(run_dir: str | Path) -> Figure:
    """Delivery Fig. 8: the planned path, the path from home to the true pad and the flown one
    in F_I (3D and side view), and a top view of the pad: both pads and the true touchdown."""
    run = Path(run_dir)
    summary = _summary(run)
    p = summary["path"]
    planned = DeliveryPath(p["h_m"], p["r_m"], p["d_m"]).sample(0.25, z_start=p["z_start_m"])
    reference = _reference_in_planned_frame(summary, p["z_start_m"])
    truth = read_columns(run / "truth.csv")
    flight = read_columns(run / "flight.csv")
    tx, ty, tz = (_floats(truth[k]) for k in ("true_mission_x_m", "true_mission_y_m", "true_mission_z_m"))
    configured, true_pad, touchdown = _pads(summary)
    size = float(p.get("pad_size_m", 1.0))
    show_ref = reference is not None and true_pad is not None and float(np.hypot(*true_pad)) > 0.01

    fig = plt.figure(figsize=(15, 5))
    ax = fig.add_subplot(1, 3, 1, projection="3d")
    ax.plot(planned[:, 0], planned[:, 1], planned[:, 2], "k--", lw=1, label="planned")
    if show_ref and reference is not None:
        ax.plot(reference[:, 0], reference[:, 1], reference[:, 2], "m-.", lw=0.8, label=TRUE_PAD_PATH_LABEL)
    ax.plot(tx, ty, tz, "g-", lw=1.2, label="flown (truth)")
    ax.scatter([configured[0]], [configured[1]], [0.0], marker="s", color="k", label=CONFIGURED_PAD_LABEL)
    if true_pad is not None:
        ax.scatter([true_pad[0]], [true_pad[1]], [0.0], marker="*", s=80, color="r", label=TRUE_PAD_LABEL)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ys = np.concatenate([ty[np.isfinite(ty)], [0.0] if true_pad is None else [true_pad[1]]])
    half = max(5.0, float(np.max(np.abs(ys))) + 1.0 if ys.size else 5.0)
    ax.set_ylim(-half, half)
    ax.set_title("Delivery path in F_I (cf. delivery Fig. 8)")
    ax.legend(loc="upper left", fontsize=7)

    ax2 = fig.add_subplot(1, 3, 2)
    ax2.plot(planned[:, 0], planned[:, 2], "k--", lw=1, label="planned")
    if show_ref and reference is not None:
        ax2.plot(reference[:, 0], reference[:, 2], "m-.", lw=0.8, label=TRUE_PAD_PATH_LABEL)
    ax2.plot(tx, tz, "g-", lw=1.2, label="flown (truth)")
    ex, ez = _estimate_in_outbound_frame(p, flight)
    ax2.plot(ex, ez, "b:", lw=1, label="flown (estimate)")
    ax2.plot([configured[0]], [0.0], "ks", label=CONFIGURED_PAD_LABEL)
    if true_pad is not None:
        ax2.plot([true_pad[0]], [0.0], "r*", ms=10, label=TRUE_PAD_LABEL)
    ax2.set_xlabel("x [m] (towards the pad)")
    ax2.set_ylabel("z [m] (up)")
    ax2.set_title("Side view")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize=7)

    # top view of the pad: a miss of a metre or two is invisible at the path's scale
    ax3 = fig.add_subplot(1, 3, 3)
    near = np.isfinite(tx) & (tz < 3.0 * size + 2.0) & (tx > -3.0 * size - 5.0)
    ax3.plot(ty[near], tx[near], "g.", ms=1.5, label="flown (truth), low near the pad")
    ax3.add_patch(
        Rectangle((configured[1] - size / 2, configured[0] - size / 2), size, size, fill=False, color="k", ls="--")
    )
    ax3.plot([configured[1]], [configured[0]], "ks", label=CONFIGURED_PAD_LABEL)
    pts = [configured]
    if true_pad is not None:
        ax3.add_patch(Rectangle((true_pad[1] - size / 2, true_pad[0] - size / 2), size, size, fill=False, color="r"))
        ax3.plot([true_pad[1]], [true_pad[0]], "r*", ms=12, label=TRUE_PAD_LABEL)
        pts.append(true_pad)
    if touchdown is not None and true_pad is not None:
        err = float(np.hypot(*(touchdown - true_pad)))
        ax3.plot([touchdown[1]], [touchdown[0]], "bx", ms=10, mew=2, label=f"touchdown (truth): {format_m(err)} off")
        pts.append(touchdown)
    c = np.mean(pts, axis=0)
    span = max(float(np.max(np.abs(np.array(pts) - c))) + size, 1.5 * size)
    ax3.set_xlim(c[1] - span, c[1] + span)
    ax3.set_ylim(c[0] - span, c[0] + span)
    ax3.set_aspect("equal", adjustable="box")
    ax3.set_xlabel("y [m] (left of travel)")
    ax3.set_ylabel("x [m] (towards the pad)")
    ax3.invert_xaxis()  # y points left: seen from above, looking along x
    ax3.set_title("At the pad (top view)")
    ax3.grid(True, alpha=0.3)
    ax3.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return fig


def _phase_spans(t: np.ndarray, phases: list[str]) -> list[tuple[float, float]]:
    """(start, end) of each run of ticks outside :data:`FIELD_PHASES`."""
    spans: list[tuple[float, float]] = []
    start = None
    for i, ph in enumerate(phases):
        off = ph not in FIELD_PHASES
        if off and start is None:
            start = float(t[i])
        elif not off and start is not None:
            spans.append((start, float(t[i])))
            start = None
    if start is not None and len(t):
        spans.append((start, float(t[-1])))
    return spans


def lyapunov_figure(run_dir: str | Path) -> Figure:
    """Delivery Fig. 9: V (estimate, log axis) above the true distance to the path (linear, its
    own axis); the phases without a vector field are shaded and named, so no gap goes unexplained."""
    run = Path(run_dir)
    summary = _summary(run)
    truth = read_columns(run / "truth.csv")
    flight = read_columns(run / "flight.csv")
    t = _floats(flight["time_s"])
    V = _floats(flight["lyapunov_m2"])
    fig, (ax_v, ax_d) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    positive = np.where(V > 0.0, V, np.nan)  # log axis: V = 0 exactly would be off the axis
    ax_v.plot(t, positive, "b-", lw=1, label="V (estimate)")
    ax_v.set_yscale("log")
    ax_v.set_ylabel("V [m^2]")
    ax_v.set_title("Vector field Lyapunov function (cf. delivery Fig. 9)")
    tt = _floats(truth["time_s"])
    # the distance counts where the vector field flies (what the summary scores); elsewhere the
    # path is not what the vehicle follows (it sits on the pad, climbs, lands): left blank
    followed = np.array([ph in FIELD_PHASES for ph in truth["phase"]])
    has_ref = "path_reference" in summary  # truth.csv's distance is to the scored reference
    ref_label = "to the scored reference path" if has_ref else "to the path"
    d_ref = np.where(followed, _floats(truth["true_path_distance_m"]), np.nan)
    ax_d.plot(tt, d_ref, "g-", lw=1, label=f"distance {ref_label} (truth)")
    if "true_planned_path_distance_m" in truth:
        d_planned = np.where(followed, _floats(truth["true_planned_path_distance_m"]), np.nan)
        if np.nanmax(np.abs(d_planned - d_ref), initial=0.0) > 0.01:
            ax_d.plot(tt, d_planned, "k--", lw=0.8, alpha=0.7, label="distance to the mission's path (truth)")
    ax_d.set_ylim(bottom=0.0)
    ax_d.set_ylabel("distance [m]")
    ax_d.set_xlabel("time [s]")
    spans = _phase_spans(t, flight["phase"])
    for ax in (ax_v, ax_d):
        for i, (a, b) in enumerate(spans):
            ax.axvspan(a, b, color="0.85", alpha=0.6, lw=0, label=NO_FIELD_LABEL if i == 0 else None)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    ref = summary.get("path_reference")
    note = textwrap.fill(f"Path distance scored against {ref}.", 150) if ref else ""
    if note:
        fig.text(0.01, 0.005, note, fontsize=7, va="bottom")
    fig.tight_layout(rect=(0.0, 0.03 + 0.02 * note.count("\n"), 1.0, 1.0))
    return fig


def plot_run(run_dir: str | Path, out_dir: str | Path | None = None) -> list[Path]:
    """Write path.png (delivery Fig. 8) and lyapunov.png (Fig. 9) into ``out_dir`` (default ``run_dir``)."""
    run = Path(run_dir)
    dest = Path(out_dir) if out_dir is not None else run
    dest.mkdir(parents=True, exist_ok=True)
    out = []
    for name, build in (("path.png", path_figure), ("lyapunov.png", lyapunov_figure)):
        fig = build(run)
        f = dest / name
        fig.savefig(f, dpi=110)
        plt.close(fig)
        out.append(f)
    return out
