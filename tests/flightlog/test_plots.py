"""Figures that cannot mislead, read from their matplotlib artists (not by comparing images):
path.png draws the true and the configured pad, lyapunov.png gives V and the distance their own
axes and names every gap, landing_scatter.png shows both ellipses, nothing clipped."""

from __future__ import annotations

import json
import math

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.patches import Ellipse

from companion.flightlog.plots import (
    CONFIGURED_PAD_LABEL,
    NO_FIELD_LABEL,
    TRUE_PAD_LABEL,
    TRUE_PAD_PATH_LABEL,
    lyapunov_figure,
    path_figure,
)
from companion_lab.campaign_output import landing_scatter
from companion_lab.demo import run_demo
from companion_sitl.scoring import REFERENCE

from .conftest import short_config

pytestmark = pytest.mark.flight


@pytest.fixture(scope="module")
def gps_only_run(tmp_path_factory):
    """GPS only with the pad 1.5 m from where it is configured: lands about that far off."""
    run = tmp_path_factory.mktemp("gps") / "run"
    r = run_demo(short_config(pad_offset_m=[1.2, -0.9]), run_dir=run, fusion=False)
    assert r.delivered and r.returned, r.failure
    assert r.pad_landing_error_m > 1.0
    return run, r


def _line(ax, label):
    found = [ln for ln in ax.get_lines() if ln.get_label() == label]
    assert found, (label, [ln.get_label() for ln in ax.get_lines()])
    return found[0]


def _pad_view(fig):
    return next(ax for ax in fig.axes if ax.get_title() == "At the pad (top view)")


def test_path_figure_draws_the_true_and_the_configured_pad(gps_only_run):
    run, r = gps_only_run
    summary = json.loads((run / "summary.json").read_text())
    true_pad = summary["true_pad_mission_m"]
    fig = path_figure(run)
    try:
        side = next(ax for ax in fig.axes if ax.get_title() == "Side view")
        assert tuple(_line(side, CONFIGURED_PAD_LABEL).get_xydata()[0]) == (0.0, 0.0)
        assert _line(side, TRUE_PAD_LABEL).get_xydata()[0] == pytest.approx([true_pad[0], 0.0])
        top = _pad_view(fig)
        # top view: x = y in F_I (left of travel), y = x in F_I
        assert tuple(_line(top, CONFIGURED_PAD_LABEL).get_xydata()[0]) == (0.0, 0.0)
        tp = _line(top, TRUE_PAD_LABEL).get_xydata()[0]
        assert tp == pytest.approx([true_pad[1], true_pad[0]])
        # the pads are as far apart as the pad was displaced
        assert math.hypot(*tp) == pytest.approx(1.5, abs=0.3)
        td = next(ln for ln in top.get_lines() if ln.get_label().startswith("touchdown (truth)"))
        assert math.dist(td.get_xydata()[0], tp) == pytest.approx(r.pad_landing_error_m, abs=1e-6)
        assert f"{r.pad_landing_error_m:.2f} m off" in td.get_label()
        # every pad and the touchdown are inside the view
        (x0, x1), (y0, y1) = sorted(top.get_xlim()), sorted(top.get_ylim())
        for px, py in ((0.0, 0.0), tuple(tp), tuple(td.get_xydata()[0])):
            assert x0 < px < x1 and y0 < py < y1
    finally:
        plt.close(fig)


def test_fused_path_figure_draws_the_path_to_the_true_pad(demo_run):
    fig = path_figure(demo_run)
    try:
        side = next(ax for ax in fig.axes if ax.get_title() == "Side view")
        ref = _line(side, TRUE_PAD_PATH_LABEL).get_xydata()
        summary = json.loads((demo_run / "summary.json").read_text())
        # it ends on the true pad, the planned one on the configured pad
        assert ref[-1] == pytest.approx([summary["true_pad_mission_m"][0], 0.0], abs=0.3)
        assert _line(side, "planned").get_xydata()[-1] == pytest.approx([0.0, 0.0], abs=0.3)
        # the estimate is drawn in the outbound F_I all the way home: it ends where it started
        est = _line(side, "flown (estimate)").get_xydata()
        est = est[np.isfinite(est).all(axis=1)]
        assert est[-1] == pytest.approx(est[0], abs=1.0)
        assert est[0][0] == pytest.approx(-summary["path"]["d_m"], abs=1.0)
    finally:
        plt.close(fig)


def test_lyapunov_figure_has_own_axes_no_symlog_and_named_gaps(demo_run):
    fig = lyapunov_figure(demo_run)
    try:
        ax_v, ax_d = fig.axes
        assert ax_v.get_yscale() == "log" and ax_d.get_yscale() == "linear"
        assert ax_v.get_ylabel() == "V [m^2]" and ax_d.get_ylabel() == "distance [m]"
        v = _line(ax_v, "V (estimate)").get_ydata()
        assert np.all(np.isnan(v) | (v > 0))  # nothing plotted at an invisible 0 of a log axis
        d = next(ln for ln in ax_d.get_lines() if "scored reference" in ln.get_label()).get_ydata()
        assert np.nanmax(d) > 0 and ax_d.get_ylim()[0] == 0.0
        # every tick without V lies in a shaded, labelled span
        labels = [p.get_label() for p in ax_v.patches]
        assert NO_FIELD_LABEL in labels
        spans = [(p.get_x(), p.get_x() + p.get_width()) for p in ax_v.patches]
        t = _line(ax_v, "V (estimate)").get_xdata()
        for ti in t[np.isnan(v)]:
            assert any(a - 1e-9 <= ti <= b + 1e-9 for a, b in spans), ti
        summary = json.loads((demo_run / "summary.json").read_text())
        assert summary["path_reference"] == REFERENCE
        assert any("scored against" in txt.get_text() for txt in fig.texts)
    finally:
        plt.close(fig)


def _campaign(seed=7):
    rng = np.random.default_rng(seed)
    fused = rng.normal(0.0, 0.03, size=(30, 2))
    gps = rng.normal([0.4, -0.9], [1.3, 0.9], size=(30, 2))

    def rows(pts):
        return [{"east_m": float(e), "north_m": float(n)} for e, n in pts]

    def stats(pts):
        err = np.hypot(pts[:, 0], pts[:, 1])
        on = np.mean((np.abs(pts) <= 0.5).all(axis=1)) * 100
        return {"mean_m": float(err.mean()), "on_pad_pct": float(on)}

    return {
        "n": 30,
        "landings": {"fusion": rows(fused), "gps_only": rows(gps)},
        "summary": {"fusion": stats(fused), "gps_only": stats(gps)},
    }, {"fusion": fused, "gps_only": gps}


def _inside(ax, lo, hi):
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    return x0 <= lo[0] and hi[0] <= x1 and y0 <= lo[1] and hi[1] <= y1


def test_landing_scatter_shows_both_ellipses_unclipped():
    result, pts = _campaign()
    fig = landing_scatter(result)
    try:
        ax, ax_pad = fig.axes[:2]
        ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
        assert len(ellipses) == 2
        span = float(np.ptp(ax.get_xlim()))
        for e in ellipses:
            # the ellipse's extent in data units, from its own path
            verts = e.get_patch_transform().transform(e.get_path().vertices)
            lo, hi = verts.min(axis=0), verts.max(axis=0)
            assert _inside(ax, lo, hi), (lo, hi, ax.get_xlim(), ax.get_ylim())
            if np.max(hi - lo) < 0.05 * span:  # too small to see on the whole spread: the pad view holds it
                assert _inside(ax_pad, lo, hi) and np.max(hi - lo) > 0.05 * float(np.ptp(ax_pad.get_xlim()))
        for p in np.vstack(list(pts.values())):
            assert _inside(ax, p, p)
        # the pad view shows the whole pad; the legend sits outside both panels
        assert _inside(ax_pad, (-0.5, -0.5), (0.5, 0.5))
        assert ax.get_legend() is None and ax_pad.get_legend() is None and fig.legends
        # and the fused ellipse is where the fused touchdowns are
        fused_e = next(e for e in ellipses if e.get_edgecolor()[:3] == pytest.approx((0.839, 0.153, 0.157), abs=0.01))
        assert fused_e.get_center() == pytest.approx(tuple(pts["fusion"].mean(axis=0)))
    finally:
        plt.close(fig)


def test_with_every_failure_variant_the_legend_covers_no_label_and_no_two_share_a_colour():
    # `campaign landing --failures`: 13 variants; the legend covered the x-axis labels and five
    # variants were drawn in the same grey
    from matplotlib.colors import to_rgba

    from companion_lab.campaign_landing import VARIANTS

    rng = np.random.default_rng(3)
    result = {"n": 5, "landings": {}, "summary": {}}
    for v in sorted(VARIANTS):
        pts = rng.normal(0.0, 0.2, size=(5, 2))
        result["landings"][v] = [{"east_m": float(e), "north_m": float(n)} for e, n in pts]
        result["summary"][v] = {"mean_m": 0.1, "on_pad_pct": 100.0, "n": 5}
    fig = landing_scatter(result)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
        legend = fig.legends[0].get_window_extent(renderer)
        for a in fig.axes[:2]:
            for text in (a.xaxis.label, *a.get_xticklabels()):
                box = text.get_window_extent(renderer)
                assert not legend.overlaps(box), (text.get_text(), legend, box)
            assert not legend.overlaps(a.get_window_extent(renderer))
        colours = [to_rgba(c.get_edgecolor()[0]) for c in fig.axes[0].collections]
        assert len(colours) == len(VARIANTS) and len(set(colours)) == len(colours), colours
    finally:
        plt.close(fig)


def test_the_distance_drawn_is_the_distance_scored(tmp_path):
    # a pad 2.5 m from its configured place: on the pad the vehicle is 2.5 m off the configured
    # path's end, which no path figure scores; the figure draws what the summary's maximum counts
    run = tmp_path / "run"
    r = run_demo(short_config(gps_bias_m=[1.0, -0.5, 0.0], pad_offset_m=[2.0, 1.5]), run_dir=run)
    assert r.delivered, r.failure
    summary = json.loads((run / "summary.json").read_text())
    fig = lyapunov_figure(run)
    try:
        lines = {ln.get_label(): ln.get_ydata() for ln in fig.axes[1].get_lines()}
        scored = next(d for label, d in lines.items() if "scored reference" in label)
        planned = next(d for label, d in lines.items() if "mission's path" in label)
        assert np.nanmax(scored) == pytest.approx(summary["path_max_truth_m"], abs=0.01)
        assert np.nanmax(planned) == pytest.approx(summary["path_max_planned_m"], abs=0.01)
        assert summary["path_max_truth_m"] < 1.0  # the pad's displacement is not in it
    finally:
        plt.close(fig)
