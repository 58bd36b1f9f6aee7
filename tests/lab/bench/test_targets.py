"""The benches' targets and ``companion bench check``: a figure past its limit (or missing) fails,
and the command's exit code says whether any did."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from companion_lab.bench.targets import BENCHES, TARGETS, Target, figure, judge


def test_every_target_names_a_bench_a_unit_and_a_finite_limit():
    assert {t.bench for t in TARGETS} == set(BENCHES)
    for t in TARGETS:
        assert t.unit and t.description and math.isfinite(t.limit) and t.limit > 0, t
    keys = [(t.bench, t.key) for t in TARGETS]
    assert len(keys) == len(set(keys))  # each target declared once


def test_figures_are_found_by_dotted_keys_and_whole_keys():
    r = {"ours/raw": 0.3, "cpu": {"companion_total_pct": 12.5, "flag": True}, "n": 3}
    assert figure(r, "ours/raw") == 0.3
    assert figure(r, "cpu.companion_total_pct") == 12.5
    assert figure(r, "n") == 3.0
    assert figure(r, "cpu.missing") is None and figure(r, "nope.x") is None
    assert figure(r, "cpu.flag") is None  # a bool is no figure
    assert figure(r, "cpu") is None  # nor is a table


@pytest.mark.parametrize(
    ("measured", "ok"),
    [(10.0, True), (50.0, True), (50.0001, False), (math.nan, False), (math.inf, False), (None, False)],
)
def test_a_figure_passes_only_at_or_under_its_limit(measured, ok):
    t = Target("ekf", "x_us", 50.0, "us", "a step")
    result = {} if measured is None else {"x_us": measured}
    (v,) = judge("ekf", result, [t])
    assert v.ok is ok
    assert ("ok" if ok else "FAILED") in v.line() and "50 us" in v.line()


def test_judge_takes_each_bench_s_own_targets():
    r = {t.key: t.limit for t in TARGETS if t.bench == "ekf"}
    verdicts = judge("ekf", r)
    assert verdicts and all(v.ok and v.target.bench == "ekf" for v in verdicts)
    with pytest.raises(ValueError, match="expected one of"):
        judge("gpu", r)


def _check(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "companion", "bench", "check", *args], capture_output=True, text=True, timeout=300
    )


def test_bench_check_exit_code_follows_the_verdicts():
    proc = _check("--only", "ekf,vision", "--ekf-n", "200", "--vision-frames", "20", "--json")
    out = json.loads(proc.stdout)
    rows = out["targets"]
    assert {r["bench"] for r in rows} == {"ekf", "vision"}
    assert len(rows) == sum(t.bench in ("ekf", "vision") for t in TARGETS)
    for r in rows:
        assert r["ok"] is (r["measured"] is not None and r["measured"] <= r["limit"]), r
    assert out["failed"] == sum(not r["ok"] for r in rows)
    assert proc.returncode == (1 if out["failed"] else 0), proc.stderr


def test_bench_check_refuses_an_unknown_bench():
    proc = _check("--only", "ekf,gpu")
    assert proc.returncode == 2
    assert "--only 'ekf,gpu'" in proc.stderr + proc.stdout
