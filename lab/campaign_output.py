"""Campaign output beside the campaigns: the landing campaign's JSON and scatter (delivery
Fig. 15), and the figures ``companion report`` draws of a campaign folder (landing scatter, Dart
estimator comparison like dart Tables 1-2). The Dart table is :func:`companion_lab.dart_campaign.campaign_table`.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from companion.flightlog.reader import LogFormatError
from companion.flightlog.report import DPI, ExtraFigure, FigureSkipped
from companion.flightlog.streams import META_FILE
from companion.units import format_cm

COLOURS = {
    "fusion": "tab:red",
    "gps_only": "tab:blue",
    "no_camera": "tab:green",
    "no_uwb": "tab:orange",
    "outer_only": "tab:purple",
    "inner_only": "tab:brown",
}
# the other variants, in the order a campaign lists them: no colour shared with the ones above
# (their tab10 colours) nor with each other
SPARE_COLOURS = (
    "tab:pink", "tab:olive", "tab:cyan", "black", "gold", "navy", "lime", "teal", "salmon", "indigo",
    "maroon", "darkgreen", "magenta", "sienna", "steelblue", "khaki", "crimson", "orchid", "chocolate",
    "slategray", "deepskyblue", "darkorange", "mediumpurple", "yellowgreen", "rosybrown", "darkcyan",
    "peru", "hotpink", "darkkhaki", "lightcoral", "darkviolet", "olivedrab", "cadetblue", "firebrick",
    "tan", "mediumseagreen", "palevioletred", "dodgerblue",
)  # fmt: skip


def variant_colours(variants: list[str]) -> dict[str, str]:
    """A distinct colour per variant: the fixed ones of COLOURS, then SPARE_COLOURS in order."""
    spare = iter(SPARE_COLOURS)
    return {v: COLOURS[v] if v in COLOURS else next(spare, "gray") for v in variants}


#: Half-width of the pad view (right panel) at least, metres.
PAD_VIEW_HALF_M = 0.75


def ellipse_2sigma(pts: np.ndarray) -> tuple[np.ndarray, float, float, float, np.ndarray] | None:
    """(centre, width, height, angle_deg, half-extent along east/north) of the 2-sigma ellipse
    of (east, north) points; None below 3 points."""
    if len(pts) < 3:
        return None
    cov = np.cov(pts.T)
    w, vecs = np.linalg.eigh(cov)
    ang = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
    half = 2.0 * np.sqrt(np.maximum(np.diag(cov), 0.0))  # the ellipse's bounding box
    return pts.mean(axis=0), 4 * math.sqrt(max(w[1], 0)), 4 * math.sqrt(max(w[0], 0)), ang, half


def landing_scatter(result: dict[str, Any]) -> Figure:
    """Delivery Fig. 15: true touchdowns per variant with their 2-sigma ellipses, on the whole
    spread (left) and on the pad (right), limits set so no point or ellipse is clipped; the
    legend sits below the panels, covering nothing."""
    from matplotlib.patches import Ellipse, Rectangle

    variants = list(result["landings"])
    colours = variant_colours(variants)
    legend_rows = math.ceil((len(variants) + 2) / 2)  # + the pad and the ellipse entries, two columns
    legend_in = 0.2 * legend_rows + 0.5  # the legend's height below the panels, inches
    fig, (ax, ax_pad) = plt.subplots(1, 2, figsize=(12, 6.2 + legend_in))
    for a in (ax, ax_pad):
        a.add_patch(
            Rectangle((-0.5, -0.5), 1.0, 1.0, fill=False, lw=1.5, color="k", label="1 x 1 m pad" if a is ax else None)
        )
    lo, hi = np.array([-0.6, -0.6]), np.array([0.6, 0.6])  # the pad, with a margin
    pad_lo, pad_hi = np.array([-PAD_VIEW_HALF_M] * 2), np.array([PAD_VIEW_HALF_M] * 2)
    for v, ls in result["landings"].items():
        pts = np.array(
            [(x["east_m"], x["north_m"]) for x in ls if x["north_m"] is not None and math.isfinite(x["north_m"])]
        )
        c = colours[v]
        s = result["summary"][v]
        if pts.size == 0:  # still in the legend: every variant's landings are counted
            ax.scatter([], [], marker="x", color=c, label=f"{v}: no touchdown drawn ({s.get('failed', 0)} failed)")
            continue
        label = f"{v}: mean {format_cm(s['mean_m'])}, on pad {s['on_pad_pct']:.0f} %"
        if "landed" in s and s["landed"] < s["n"]:  # the landings not drawn: no touchdown on the pad's side
            label += f", {s['landed']} of {s['n']} drawn"
        if s.get("failed"):
            label += f", {s['failed']} failed"
        ax.scatter(pts[:, 0], pts[:, 1], marker="x", color=c, label=label)
        ax_pad.scatter(pts[:, 0], pts[:, 1], marker="x", color=c)
        lo, hi = np.minimum(lo, pts.min(axis=0)), np.maximum(hi, pts.max(axis=0))
        e = ellipse_2sigma(pts)
        if e is None:
            continue
        centre, width, height, ang, half = e
        lo, hi = np.minimum(lo, centre - half), np.maximum(hi, centre + half)
        for a in (ax, ax_pad):
            a.add_patch(Ellipse(tuple(centre), width, height, angle=ang, fill=False, color=c, ls="--", lw=1.5))
        if np.all(np.abs(centre) + half <= 2.0):  # a tight cluster: make the pad view hold all of it
            pad_lo, pad_hi = np.minimum(pad_lo, centre - half), np.maximum(pad_hi, centre + half)
    # square views around everything (equal scale on both axes), 8 % margin
    for a, (low, high) in ((ax, (lo, hi)), (ax_pad, (pad_lo, pad_hi))):
        mid, span = (low + high) / 2.0, float(np.max(high - low)) / 2.0 * 1.08
        a.set_xlim(mid[0] - span, mid[0] + span)
        a.set_ylim(mid[1] - span, mid[1] + span)
        a.set_aspect("equal", adjustable="box")
        a.set_xlabel("east of the pad centre [m]")
        a.grid(True, alpha=0.3)
    ax.set_ylabel("north of the pad centre [m]")
    ax.set_title(f"True touchdowns, {result['n']} landings per variant", fontsize=10)
    ax_pad.set_title("On the pad (same data, zoomed)", fontsize=10)
    ax.plot([], [], "k--", lw=1.5, label="2-sigma ellipse per variant (cf. delivery Fig. 15)")
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0.0, legend_in / fig.get_figheight(), 1.0, 1.0))  # the legend's room kept free
    return fig


def write_outputs(result: dict[str, Any], out_dir: Path) -> list[Path]:
    """landing_campaign.json and landing_scatter.png (delivery Fig. 15) into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    js = out_dir / "landing_campaign.json"
    js.write_text(json.dumps(result, indent=1, default=lambda o: None))
    fig = landing_scatter(result)
    png = out_dir / "landing_scatter.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return [js, png]


def landing_scatter_figure(run: Path, out: Path) -> Path:
    p = run / "landing_campaign.json"
    if not p.exists():
        raise FigureSkipped("no landing_campaign.json (written by `companion campaign landing`)")
    try:
        result = json.loads(p.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise LogFormatError(f"{p}: not valid JSON: {err}") from None
    missing = [k for k in ("n", "summary", "landings") if not isinstance(result, dict) or k not in result]
    if missing:
        raise LogFormatError(f"{p}: not a landing campaign result (missing key(s) {missing})")
    with tempfile.TemporaryDirectory() as td:  # write_outputs also rewrites the JSON: keep the input untouched
        files = write_outputs(result, Path(td))
        png = next(f for f in files if f.suffix == ".png")
        dest = out / "landing_scatter.png"
        shutil.copyfile(png, dest)
    return dest


def _dart_result(run: Path) -> tuple[Path, dict[str, Any]]:
    skip = {META_FILE, "summary.json", "landing_campaign.json"}
    for p in sorted(run.glob("*.json")):
        if p.name in skip:
            continue
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError):
            continue
        est = d.get("estimators") if isinstance(d, dict) else None
        if isinstance(est, dict) and est and all(isinstance(v, dict) and "std_cm" in v for v in est.values()):
            return p, d
    raise FigureSkipped("no Dart campaign JSON (written by `companion campaign dart --json FILE`)")


def dart_estimators_figure(run: Path, out: Path) -> Path:
    p, d = _dart_result(run)
    names = list(d["estimators"])
    try:
        est = np.array([d["estimators"][n]["std_cm"] for n in names], dtype=float).reshape(len(names), 3)
        tru = np.array([d["estimators"][n].get("truth_std_cm", [math.nan] * 3) for n in names], dtype=float)
        tru = tru.reshape(len(names), 3)
    except (TypeError, ValueError) as err:
        raise LogFormatError(f"{p}: 'std_cm' / 'truth_std_cm' must be three numbers per estimator ({err})") from None
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.5), sharey=True)
    x = np.arange(len(names))
    for i, (ax, axis) in enumerate(zip(axes, ("x (right)", "y (up)", "z (from the wall)"), strict=True)):
        ax.bar(x - 0.2, est[:, i], 0.4, color="tab:blue", label="estimated - desired (dart eq 22)")
        ax.bar(x + 0.2, tru[:, i], 0.4, color="tab:gray", label="true - desired")
        ax.set_xticks(x, names, rotation=20, fontsize=8)
        ax.set_title(f"axis {axis}")
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].set_ylabel("std of the position error [cm]")
    axes[0].legend(fontsize=8)
    fig.suptitle(
        f"Dart hover at 4 m: estimator comparison, {d.get('n', '?')} run(s) per estimator, seed {d.get('seed', '?')} "
        "(cf. dart Tables 1-2)",
        fontsize=10,
    )
    fig.tight_layout()
    f = out / "dart_estimators.png"
    fig.savefig(f, dpi=DPI)
    plt.close(fig)
    return f


# The figures ``companion report`` adds after the run's own, in this order.
CAMPAIGN_FIGURES = (
    ExtraFigure("landing_scatter.png", "landing campaign scatter (Fig. 15)", landing_scatter_figure),
    ExtraFigure("dart_estimators.png", "Dart estimator comparison (Tables 1-2)", dart_estimators_figure),
)
