"""`companion report`: the papers' figures from a run folder, as non-trivial PNGs."""

from __future__ import annotations

import json
import math

import matplotlib.image as mpimg
import numpy as np
import pytest

from companion.cli.main import main
from companion.flightlog.reader import LogFormatError
from companion.flightlog.report import make_report
from companion_lab.campaign_output import CAMPAIGN_FIGURES
from companion_lab.demo import run_demo

from .conftest import short_config

pytestmark = pytest.mark.flight

FLIGHT_FIGURES = ("path.png", "lyapunov.png", "landing_3d.png", "landing_axes.png", "gps_bias.png")


def _assert_real_image(path, min_w=600, min_h=300):
    img = mpimg.imread(path)
    assert img.shape[0] >= min_h and img.shape[1] >= min_w, (path.name, img.shape)
    rgb = img[..., :3]
    assert np.std(rgb) > 0.05, path.name  # not blank
    # drawn in colour (the sources have their own colours), not just axes and text
    assert np.mean(np.ptp(rgb, axis=2) > 0.3) > 0.002, path.name


def _by_name(figs):
    return {f.name: f for f in figs}


def test_report_of_the_demo_run(demo_run, tmp_path):
    figs = _by_name(make_report(demo_run, tmp_path / "rep", extra=CAMPAIGN_FIGURES))
    for name in FLIGHT_FIGURES:
        assert figs[name].path == tmp_path / "rep" / name, figs[name].skipped
        _assert_real_image(figs[name].path)
    assert figs["landing_scatter.png"].path is None and "landing_campaign.json" in figs["landing_scatter.png"].skipped
    assert figs["dart_estimators.png"].path is None and "Dart campaign" in figs["dart_estimators.png"].skipped


def _landing_campaign(rng, n=12):
    landings, summary = {}, {}
    for v, sd, off in (("fusion", 0.05, 0.0), ("gps_only", 0.6, 0.4)):
        pts = rng.normal(off, sd, (n, 2))
        landings[v] = [
            {"seed": k, "error_m": float(math.hypot(*p)), "north_m": float(p[0]), "east_m": float(p[1]),
             "on_pad": bool(abs(p[0]) <= 0.5 and abs(p[1]) <= 0.5), "delivered": True, "failure": ""}
            for k, p in enumerate(pts)
        ]  # fmt: skip
        e = np.hypot(pts[:, 0], pts[:, 1])
        summary[v] = {"n": n, "landed": n, "mean_m": float(e.mean()), "median_m": float(np.median(e)),
                      "p95_m": float(np.percentile(e, 95)), "max_m": float(e.max()),
                      "on_pad_pct": 100.0 * np.mean([x["on_pad"] for x in landings[v]])}  # fmt: skip
    return {"n": n, "seed": 1, "params": "landing_campaign.toml", "summary": summary, "landings": landings}


def _dart_campaign(rng):
    est = {}
    for name, gimbal in (("FCF-CF", "fixed"), ("FCF-MF", "fixed"), ("SCF-MF-2DOF", "2dof"), ("SCF-MF-3DOF", "3dof")):
        est[name] = {"gimbal": gimbal, "std_cm": rng.uniform(1, 10, 3).tolist(),
                     "truth_std_cm": rng.uniform(1, 10, 3).tolist(), "samples": 100}  # fmt: skip
    return {"n": 1, "seed": 0, "duration_s": 25.0, "settle_s": 8.0, "estimators": est}


def test_campaign_results_get_their_figures(tmp_path):
    rng = np.random.default_rng(5)
    camp = tmp_path / "campaign"
    camp.mkdir()
    text = json.dumps(_landing_campaign(rng), indent=1)
    (camp / "landing_campaign.json").write_text(text)
    (camp / "dart_hover.json").write_text(json.dumps(_dart_campaign(rng)))
    figs = _by_name(make_report(camp, extra=CAMPAIGN_FIGURES))
    for name in ("landing_scatter.png", "dart_estimators.png"):
        assert figs[name].path == camp / name, figs[name].skipped
        _assert_real_image(figs[name].path, min_w=500)
    assert (camp / "landing_campaign.json").read_text() == text  # the input is left untouched
    # a campaign folder has no flight: those figures are skipped with the reason, not fatal
    assert figs["landing_axes.png"].path is None and "run.json" in figs["landing_axes.png"].skipped


def test_gps_only_run_skips_the_fusion_figures(tmp_path):
    run = tmp_path / "gps"
    r = run_demo(short_config(), run_dir=run, fusion=False)
    assert r.delivered
    figs = _by_name(make_report(run))
    assert figs["path.png"].path is not None and figs["lyapunov.png"].path is not None
    assert "GPS-only" in figs["landing_axes.png"].skipped and "GPS-only" in figs["landing_3d.png"].skipped
    assert figs["gps_bias.png"].path is None and "no rows" in figs["gps_bias.png"].skipped


def test_without_simulator_truth_the_path_comes_from_the_logs(run_copy):
    # what a `companion fly` folder looks like: no truth.csv / summary.json / flight.csv
    for name in ("truth.csv", "summary.json", "flight.csv"):
        (run_copy / name).unlink()
    figs = _by_name(make_report(run_copy))
    for name in FLIGHT_FIGURES:
        _assert_real_image(figs[name].path)


def test_a_flight_cut_short_mid_line_still_gets_its_figures(run_copy, capsys):
    # a killed flight leaves truth.csv and flight.csv ending in half a row
    for name, keep in (("truth.csv", 0.5), ("flight.csv", 0.6)):
        data = (run_copy / name).read_bytes()
        cut = int(len(data) * keep)
        assert data[cut - 1 : cut] != b"\n"  # mid-line, not at a row's end
        (run_copy / name).write_bytes(data[:cut])
    assert main(["report", str(run_copy)]) == 0
    assert "5 figure(s) written" in capsys.readouterr().out
    for name in FLIGHT_FIGURES:
        _assert_real_image(run_copy / name)


def test_malformed_csv_is_an_error_naming_file_and_column(run_copy, capsys):
    lines = (run_copy / "ekf.csv").read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[5].split(",")
    cells[header.index("bias_east_m")] = "1.2.3"
    lines[5] = ",".join(cells)
    (run_copy / "ekf.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(LogFormatError, match=r"ekf\.csv: line 6, column 'bias_east_m': '1\.2\.3'"):
        make_report(run_copy)
    assert main(["report", str(run_copy)]) == 2
    assert "ekf.csv: line 6, column 'bias_east_m'" in capsys.readouterr().err


def test_cli_report(run_copy, capsys):
    assert main(["report", str(run_copy), "--out", str(run_copy / "figs")]) == 0
    out = capsys.readouterr().out
    assert "5 figure(s) written, 2 skipped" in out and "skipped: no landing_campaign.json" in out
    assert sorted(p.name for p in (run_copy / "figs").iterdir()) == sorted(FLIGHT_FIGURES)


@pytest.mark.parametrize("state", ["empty", "missing"])
def test_a_demo_folder_without_its_summary_still_gets_its_figures(run_copy, capsys, caplog, state):
    # a full disk at the flight's end (an older version left summary.json empty): said, not refused
    if state == "empty":
        (run_copy / "summary.json").write_text("")
    else:
        (run_copy / "summary.json").unlink()
    assert main(["report", str(run_copy), "--out", str(run_copy / "figs")]) == 0
    assert "5 figure(s) written" in capsys.readouterr().out
    for name in FLIGHT_FIGURES:
        _assert_real_image(run_copy / "figs" / name)
    said = [r.getMessage() for r in caplog.records if "summary.json" in r.getMessage()]
    assert said == [
        f"{run_copy / 'summary.json'}: {state}"
        + (" (the flight's end could not write it)" if state == "empty" else "")
        + "; the path figures are drawn from the logs instead"
    ]
