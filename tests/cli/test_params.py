"""``companion params show`` and ``params check``: every tunable listed with its unit, limits and
description."""

from __future__ import annotations

import pytest

from companion.cli.main import main


@pytest.mark.parametrize(
    "line",
    [
        "landing.ekf.position_process_sigma_m_per_sqrt_s = 0.05 [m/sqrt(s)] (> 0.0, <= 5.0)  Q_f (eq 6) position",
        "landing.ekf.gate_probability = 0.9999 [-] (> 0.5, < 1.0)  the gate's chi-square probability",
        "landing.detector.full_search_every = 30 [-] (>= 1, <= 100000)  a full-frame search at least every N",
        "landing.detector.max_reprojection_error_px = 4.0 [px] (> 0.0, <= 1000.0)  poses that reproject worse",
        "landing.multilateration.max_range_m = None [m] (> 0.0, <= 1000.0)  ranges longer than this are refused",
        "landing.multilateration.seed = 0 [-] (>= 0, <= 9223372036854775807)  seed of the subset sampling",
        "mission.descent.xy_gain_1_s = 3.0 [1/s] (> 0.0, <= 10.0)  horizontal speed per metre off the target",
        "mission.descent.touchdown_height_m = 0.15 [m] (>= -1.0, <= 2.0)  below this height only the vertical",
    ],
)
def test_params_show_lists_the_tuning_of_estimators_solvers_and_descent(capsys, line):
    assert main(["params", "show"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert any(x.startswith(line) for x in out), line
    assert {"[landing.ekf]", "[landing.detector]", "[landing.multilateration]", "[mission.descent]"} <= set(out)


def test_params_check_refuses_a_bad_tuning_value_naming_the_key(tmp_path, capsys):
    f = tmp_path / "v.toml"
    f.write_text("[landing.detector]\nerr_ratio_threshold = 1.5\n")
    assert main(["params", "check", str(f)]) == 1
    err = capsys.readouterr().err
    assert "landing.detector.err_ratio_threshold = 1.5: Input should be less than or equal to 1" in err
