"""``companion bench dropzone``: the figures' bench runs, is deterministic for a seed, and refuses
bad input with a clear error."""

from __future__ import annotations

import json

import pytest

from companion.cli.main import main
from companion.config import DropZoneConfig
from companion_lab.bench.drop_zone import bench_drop_zone, run_draw


def test_bench_holds_for_a_box_not_for_a_clear_pad_and_repeats() -> None:
    a = bench_drop_zone(2, seed=4, fps=5.0, scenarios=("none", "box"))
    assert a["scenarios"]["none"]["holds"] == 0
    assert a["scenarios"]["box"]["holds"] == 2
    assert a["scenarios"]["box"]["max_time_to_decide_s"] < 5.0  # caught in the descent, before 5 m
    b = bench_drop_zone(2, seed=4, fps=5.0, scenarios=("none", "box"))
    for kind in ("none", "box"):
        assert a["scenarios"][kind]["holds"] == b["scenarios"][kind]["holds"]
        assert a["scenarios"][kind]["median_time_to_decide_s"] == b["scenarios"][kind]["median_time_to_decide_s"]


def test_cli_prints_the_table_and_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "dropzone", "--draws", "1", "--fps", "5", "--scenarios", "box"]) == 0
    assert "box on the pad" in capsys.readouterr().out
    assert main(["bench", "dropzone", "--draws", "1", "--fps", "5", "--scenarios", "none", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["scenarios"]["none"]["holds"] == 0


@pytest.mark.parametrize(("argv", "match"), [(["--scenarios", "tree"], "unknown"), (["--fps", "0.5"], "--fps")])
def test_cli_bad_input(argv: list[str], match: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "dropzone", *argv]) != 0
    assert match in capsys.readouterr().err


def test_cli_refuses_zero_draws() -> None:
    with pytest.raises(SystemExit):
        main(["bench", "dropzone", "--draws", "0"])


def test_bench_refuses_bad_arguments() -> None:
    with pytest.raises(ValueError, match="draws"):
        bench_drop_zone(0)
    with pytest.raises(ValueError, match="fps"):
        bench_drop_zone(1, fps=100.0)
    with pytest.raises(ValueError, match="scenario"):
        bench_drop_zone(1, scenarios=("tree",))  # type: ignore[arg-type]


def test_only_some_draws_fly_those_draws(capsys: pytest.CaptureFixture[str]) -> None:
    one = bench_drop_zone(3, seed=4, fps=5.0, scenarios=("box",), only=[2])
    assert one["draws"] == 1 and one["only"] == [2]
    alone = run_draw("box", 2, 4, 5.0, DropZoneConfig(enabled=True))
    assert alone["hold"] and one["scenarios"]["box"]["holds"] == 1
    assert one["scenarios"]["box"]["median_time_to_decide_s"] == alone["time_to_decide_s"]
    with pytest.raises(ValueError, match="only"):
        bench_drop_zone(3, only=[3])
    assert main(["bench", "dropzone", "--draws", "3", "--draw", "x"]) != 0
    assert "--draw" in capsys.readouterr().err
    assert main(["bench", "dropzone", "--draws", "3", "--draw", "5"]) != 0
    assert "not in 0-2" in capsys.readouterr().err
