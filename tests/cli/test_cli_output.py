"""The command line reads cleanly: help with defaults on every option, no wrapping when the
output is not a terminal, flight time (not the machine's uptime) in the progress bar, distances
never rounded to 0.00, folders created for the files asked for."""

from __future__ import annotations

import argparse
import json
import math
from types import SimpleNamespace

import pytest

from companion.cli.console import make_console
from companion.cli.demo import flight_time_s
from companion.cli.helptext import all_parsers
from companion.cli.main import build_parser, main
from companion.config import shipped_params_path
from companion.units import format_cm, format_m
from companion_sitl.scoring import REFERENCE

_NOT_OPTIONS = (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)


def _options():
    parser, failed = build_parser()
    assert not failed
    for prog, p in all_parsers(parser):
        formatter = p._get_formatter()
        for action in p._actions:
            if not isinstance(action, _NOT_OPTIONS):
                yield prog, action, formatter._expand_help(action) if action.help else ""


def test_every_option_has_help_and_its_default():
    options = list(_options())
    assert len(options) > 80  # every sub-command was walked
    missing = [(prog, a.option_strings or a.dest) for prog, a, text in options if not text.strip()]
    assert not missing, missing
    for prog, a, text in options:
        takes_value = a.nargs != 0 and not a.required and a.nargs != "+"
        if takes_value:
            assert "default" in text, (prog, a.option_strings, text)
        if takes_value and a.default not in (None, False, argparse.SUPPRESS):
            assert str(a.default) in text, (prog, a.option_strings, text)


def test_help_prints_the_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["bench", "sim", "--help"])
    out = capsys.readouterr().out
    assert "(default: 2)" in out and "(default: 1)" in out


def test_console_does_not_wrap_when_not_a_terminal(capsys):
    console = make_console()
    assert not console.is_terminal
    long = "x" * 150 + " end"
    console.print(long)
    assert long in capsys.readouterr().out


@pytest.mark.flight
def test_demo_output_is_not_wrapped_and_names_its_path_reference(tmp_path, capsys):
    out = tmp_path / "run"
    params = str(shipped_params_path("sitl_short.toml"))
    assert main(["demo", "--params", params, "--gps-only", "--quiet", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.strip() == f"scored reference: {REFERENCE}" for line in lines)
    assert any("run folder" in line and "lyapunov.png)" in line for line in lines)
    assert all(len(line) > 80 or not line.startswith(" " * 20) for line in lines)  # no continuation lines
    landing = next(line for line in lines if "landing error on the pad" in line)
    summary = json.loads((out / "summary.json").read_text())
    assert landing.split()[-2:] == format_m(summary["pad_landing_error_m"]).split()


def test_progress_shows_flight_time_not_the_clock():
    """In real time the shell's clock is the machine's monotonic clock (its uptime)."""
    summary = SimpleNamespace(takeoff_time_s=None)
    shell = SimpleNamespace(now=lambda: 86_412.5, mission=SimpleNamespace(summary=summary))
    assert flight_time_s(shell) == 0.0
    summary.takeoff_time_s = 86_400.0
    assert flight_time_s(shell) == pytest.approx(12.5)


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (0.0, "0 m"),
        (0.0013, "1.3 mm"),
        (0.004, "4.0 mm"),
        (0.044, "44 mm"),
        (0.1, "0.10 m"),
        (2.584, "2.58 m"),
        (-0.002, "-2.0 mm"),
        (3e-6, "0.003 mm"),
        (math.nan, "n/a"),
    ],
)
def test_format_m_never_prints_zero_for_an_error(value, text):
    assert format_m(value) == text


def test_format_cm():
    assert format_cm(0.044) == "4.4 cm" and format_cm(0.0002) == "0.2 mm" and format_cm(0.0) == "0.0 cm"
    for v in (1e-7, 4e-4, 0.003, 0.2):  # a non-zero distance never reads as zero
        assert float(format_cm(v).split()[0]) != 0.0 and float(format_m(v).split()[0]) != 0.0


@pytest.mark.flight
def test_campaign_dart_json_into_a_new_folder(tmp_path, capsys):
    dest = tmp_path / "not" / "yet" / "dart.json"
    args = ["campaign", "dart", "--estimator", "FCF-CF", "--n", "1", "--duration", "6", "--settle", "1"]
    assert main([*args, "--json", str(dest), "--quiet"]) == 0
    assert json.loads(dest.read_text())["estimators"]
    assert f"wrote {dest}" in capsys.readouterr().out


def test_bench_distances_are_not_rounded_to_zero():
    from companion.cli.bench import _bench_value

    assert _bench_value("ours_median_position_error_m", 0.0022) == "2.2 mm"
    assert _bench_value("ours/raw", 0.38) == "0.38"
    assert _bench_value("n_frames", 12.0) == "12"
