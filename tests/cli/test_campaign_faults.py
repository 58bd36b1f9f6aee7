"""`companion campaign landing --faults`: the campaign JSON carries every landing's row by fault,
a landing that breaks the safety contract ends the command with exit 1, and options that do not
go with a fault campaign are refused (exit 2)."""

from __future__ import annotations

import json
from dataclasses import asdict

import pytest

from companion.cli.main import main
from companion_lab import fault_campaign


def _flown(off_pad_seeds: set[int]):
    def fly(config, d):
        off = d.seed in off_pad_seeds
        return {
            **asdict(d),
            "fired": True,
            "failsafe_required": fault_campaign.failsafe_required(config, d),
            "failsafe_s": 1.0 if fault_campaign.failsafe_required(config, d) else None,
            "released_on_pad": not off,
            "released_off_pad": off,
            "lost": "",
            "touchdown_ne_m": (14.0, 14.0),
            "touchdown_speed_m_s": 0.7,
        }

    return fly


@pytest.mark.parametrize(("off_pad", "code"), [(set(), 0), ({2001}, 1)])
def test_the_json_holds_each_landing_and_the_exit_says_the_contract(tmp_path, monkeypatch, capsys, off_pad, code):
    monkeypatch.setattr(fault_campaign, "fly_fault_landing", _flown(off_pad))
    out = tmp_path / "faults"
    argv = ["campaign", "landing", "--faults", "stall_15s,link_cut", "--n", "2", "--seed", "2", "--out", str(out)]
    assert main([*argv, "--quiet"]) == code
    result = json.loads((out / "fault_campaign.json").read_text())
    assert result["faults"] == ["stall_15s", "link_cut"] and result["n"] == 2 and result["seed"] == 2
    assert [x["seed"] for x in result["landings"]["stall_15s"]] == [2000, 2001]
    assert [x["seed"] for x in result["landings"]["link_cut"]] == [2002, 2003]
    s = result["summary"]["stall_15s"]
    assert (s["landings"], s["released_off_pad"], s["failsafe_reached"]) == (2, len(off_pad), 2)
    err = capsys.readouterr().err
    assert ("stall_15s: 1 parcel(s) released off the pad" in err) == bool(off_pad)


@pytest.mark.parametrize(
    "extra",
    [["--faults", "stall_2s"], ["--faults", "all", "--autopilot", "px4"], ["--faults", "all", "--jobs", "2"]],
)
def test_what_a_fault_campaign_refuses(tmp_path, capsys, extra):
    assert main(["campaign", "landing", "--out", str(tmp_path / "f"), *extra]) == 2
    assert "--faults" in capsys.readouterr().err
