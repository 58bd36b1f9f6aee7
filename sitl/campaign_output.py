"""Campaign output beside the campaigns: the landing campaign's JSON and scatter (delivery
Fig. 15), and the figures ``companion report`` draws of a campaign folder (landing scatter, Dart
estimator comparison like dart Tables 1-2). The Dart table is :func:`companion_sitl.dart_campaign.campaign_table`.
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

from companion.flightlog.reader import LogFormatError
from companion.flightlog.recorder import META_FILE
from companion.flightlog.report import DPI, ExtraFigure, FigureSkipped


def write_outputs(result: dict[str, Any], out_dir: Path) -> list[Path]:
    """summary.json and a scatter like delivery Fig. 15 (true touchdowns, 2-sigma ellipses)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse, Rectangle

    out_dir.mkdir(parents=True, exist_ok=True)
    js = out_dir / "landing_campaign.json"
    js.write_text(json.dumps(result, indent=1, default=lambda o: None))
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.add_patch(Rectangle((-0.5, -0.5), 1.0, 1.0, fill=False, lw=1.5, color="k", label="1 x 1 m pad"))
    colours = {
        "fusion": "tab:red",
        "gps_only": "tab:blue",
        "no_camera": "tab:green",
        "no_uwb": "tab:orange",
        "outer_only": "tab:purple",
        "inner_only": "tab:brown",
    }
    for v, ls in result["landings"].items():
        pts = np.array([(x["east_m"], x["north_m"]) for x in ls if math.isfinite(x["north_m"])])
        if pts.size == 0:
            continue
        c = colours.get(v, "gray")
        s = result["summary"][v]
        ax.scatter(
            pts[:, 0],
            pts[:, 1],
            marker="x",
            color=c,
            label=f"{v}: mean {s['mean_m'] * 100:.1f} cm, on pad {s['on_pad_pct']:.0f} %",
        )
        if len(pts) >= 3:
            cov = np.cov(pts.T)
            w, vecs = np.linalg.eigh(cov)
            ang = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
            ax.add_patch(
                Ellipse(
                    pts.mean(axis=0),
                    4 * math.sqrt(max(w[1], 0)),
                    4 * math.sqrt(max(w[0], 0)),
                    angle=ang,
                    fill=False,
                    color=c,
                    ls="--",
                )
            )
    ax.set_xlabel("east of the pad centre [m]")
    ax.set_ylabel("north of the pad centre [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_title(
        f"True touchdowns, {result['n']} landings per variant\n(2-sigma ellipses; cf. delivery Fig. 15)", fontsize=10
    )
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
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
