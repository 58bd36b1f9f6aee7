"""`companion campaign`'s exit codes count every landing: a landing that failed, and a parity that
does not hold, end the command with exit 1."""

from __future__ import annotations

import json
import math

import pytest

from companion.cli.main import main
from companion_lab import landing_campaign, real_campaign


def _row(task, delivered: bool, home: bool = False) -> dict:
    return {
        "seed": task.draw.seed,
        "error_m": 0.02 if delivered else math.nan,
        "north_m": 0.02 if delivered else math.nan,
        "east_m": 0.0 if delivered else math.nan,
        "on_pad": delivered,
        "delivered": delivered,
        "home_with_parcel": home,
        "pad_tries": 0,
        "failure": "" if delivered or home else "mission timed out in landing_pad",
        "sim_time_s": 30.0,
        "gps_bias_m": [0.0, 0.0],
        "pad_offset_m": [0.0, 0.0],
        "wind_m_s": 0.0,
    }


@pytest.mark.parametrize(
    ("outcomes", "code", "landed", "failed"),
    [
        ([True, True, True], 0, 3, 0),
        ([True, False, True], 1, 2, 1),
        (["home", "home", True], 0, 1, 0),  # the parcel brought home by the policy is not a failure
    ],
)
def test_landing_campaign_counts_every_landing_and_fails_on_a_failed_one(
    monkeypatch, tmp_path, capsys, outcomes, code, landed, failed
):
    it = iter(outcomes)

    def fly(task):
        o = next(it)
        return _row(task, o is True, home=o == "home")

    monkeypatch.setattr(landing_campaign, "fly_landing", fly)
    out = tmp_path / "camp"
    argv = ["campaign", "landing", "--n", "3", "--variants", "fusion", "--jobs", "1", "--quiet", "--out", str(out)]
    assert main(argv) == code
    captured = capsys.readouterr()
    assert f"{landed} of 3" in captured.out
    summary = json.loads((out / "landing_campaign.json").read_text())["summary"]["fusion"]
    assert (summary["n"], summary["landed"], summary["failed"]) == (3, landed, failed)
    if failed:
        assert f"fusion {failed} of 3" in captured.err and "landing_campaign.json" in captured.err
    else:
        assert "failed landings" not in captured.err


@pytest.mark.parametrize(("within", "agree", "code"), [(True, True, 0), (False, True, 1), (True, False, 1)])
def test_parity_exits_1_when_it_prints_no(monkeypatch, tmp_path, capsys, within, agree, code):
    figures = {"mean_m": 0.05, "p90_m": 0.08, "max_m": 0.1, "n": 3, "landed": 3}
    comparison = {
        "seeds": [1, 2, 3],
        "predicted": figures,
        "real": figures,
        "ratio_predicted_to_real": {"mean_m": 1.0, "p90_m": 1.0, "max_m": 1.0},
        "within_factor": 1.5,
        "mean_and_p90_within_factor": within,
        "failure_classes_agree": agree,
        "failure_class_disagreements": [] if agree else [2],
    }

    def run_parity(*args, **kwargs):
        return {"profile": "px4-sih", "comparison": {"fusion": comparison}, "out_dir": str(tmp_path)}

    monkeypatch.setattr(real_campaign, "run_parity", run_parity)
    assert main(["campaign", "parity", "--autopilot", "px4", "--n", "3"]) == code
    out = capsys.readouterr().out
    assert ("NO" in out) == (code == 1)


@pytest.mark.parametrize(
    "argv",
    [
        ["campaign", "landing", "--weather", "--n", "1"],  # the ideal profile
        ["campaign", "landing", "--weather", "--n", "1", "--profile", "px4-sih"],
        ["campaign", "landing", "--weather", "--n", "1", "--autopilot", "px4"],
        ["campaign", "parity", "--weather", "--n", "1", "--autopilot", "px4"],
    ],
)
def test_weather_is_refused_where_there_is_no_firmware_weather(argv, tmp_path, capsys):
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    assert "--weather needs" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_weather_on_the_profile_keeps_the_drawn_gusts(monkeypatch, tmp_path):
    seen = {}

    def fake(n, seed, variants, params, progress, **kw):
        seen.update(kw)
        raise SystemExit(0)

    monkeypatch.setattr(landing_campaign, "run_landing_campaign", fake)
    with pytest.raises(SystemExit):
        main(["campaign", "landing", "--weather", "--n", "1", "--profile", "arducopter-sitl", "--out", str(tmp_path)])
    assert seen["profile"] == "arducopter-sitl"
    assert seen["tuning"]["sim"] == {"profile_weather": True}
    assert "velocity_bias_tau_s" in seen["tuning"]["mission"]  # still the firmware's tuning


@pytest.mark.parametrize("command", [["landing"], ["parity", "--autopilot", "px4"]])
@pytest.mark.parametrize("variants", ["fusion,bogus", " , "])
def test_an_unknown_variant_is_one_line_and_exit_2_before_anything_flies(command, variants, capsys, tmp_path):
    code = main(["campaign", *command, "--variants", variants, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert "--variants" in err and "choose from" in err and "fusion" in err, err
    assert not (tmp_path / "out").exists()  # nothing written
