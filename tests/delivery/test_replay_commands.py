"""Ground commands travel as :class:`~companion.events.CommandKind` from the wire to the mission's
decision; their names are text only where they are written (commands.csv) and read back (the
replay, which parses commands.csv's ``kind`` once and refuses a name it does not know)."""

from __future__ import annotations

import csv

import pytest

from companion.config import shipped_params_path
from companion.delivery.mission import CommandOutcome
from companion.delivery.replay import InputKind, read_inputs, replay_run
from companion.events import CommandKind, Phase
from companion.flightlog.reader import LogFormatError, Table
from companion_lab.demo import run_demo
from companion_sitl.params import load_simulated_config


def _fly_with_commands(run) -> list[str]:  # type: ignore[no-untyped-def]
    config = load_simulated_config(shipped_params_path("sitl_short.toml"), overrides={"sim": {"seed": 3}})
    replies: list[str] = []
    inbound_ticks = [0]

    def on_tick(shell, out) -> None:  # type: ignore[no-untyped-def]
        if not replies and out.phase is Phase.OUTBOUND:
            reply = shell.command(CommandKind.RETURN, "test")
            assert reply.outcome is CommandOutcome.ACCEPTED
            replies.append(reply)
        elif len(replies) == 1 and out.phase is Phase.INBOUND:
            inbound_ticks[0] += 1
            if inbound_ticks[0] == 30:
                replies.append(shell.command(CommandKind.LAND, "test"))

    run_demo(config, run_dir=run, on_tick=on_tick)
    return replies


@pytest.fixture(scope="module")
def commanded_run(tmp_path_factory):  # type: ignore[no-untyped-def]
    run = tmp_path_factory.mktemp("commanded") / "run"
    replies = _fly_with_commands(run)
    return run, replies


def test_a_flight_with_ground_commands_replays_bit_for_bit(commanded_run, tmp_path) -> None:  # type: ignore[no-untyped-def]
    run, replies = commanded_run
    cmds = Table(run / "commands.csv")
    rows = [(cmds.text(k, "source"), cmds.text(k, "kind"), cmds.text(k, "detail")) for k in range(len(cmds))]
    assert rows == [("ground", "return", "test"), ("ground", "land", "test")][: len(replies)]
    assert replies[0] == "returning home along the path"
    inputs, _ = read_inputs(run)
    commands = [i.payload[1] for i in inputs if i.kind is InputKind.COMMAND]
    assert commands == [CommandKind.RETURN, CommandKind.LAND][: len(replies)]
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical and not rep.notes, "\n".join(rep.lines())


def test_a_reply_that_differs_is_noted_by_the_commands_name(commanded_run, tmp_path) -> None:  # type: ignore[no-untyped-def]
    run, _ = commanded_run
    rows = list(csv.reader((run / "commands.csv").open(newline="")))
    edited = [[*r[:5], "something else"] if r[2] == "ground" else r for r in rows]
    copy = tmp_path / "run"
    copy.mkdir()
    for f in run.iterdir():
        if f.is_file():
            (copy / f.name).write_bytes(f.read_bytes())
    with (copy / "commands.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(edited)
    rep = replay_run(copy, tmp_path / "replayed")
    assert any("ground command 'return' replied 'returning home along the path' in replay" in n for n in rep.notes)
    edited[1][3] = "fly"
    with (copy / "commands.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(edited)
    with pytest.raises(
        LogFormatError, match=r"line 2, column 'kind': 'fly' is not one of 'hold', 'return', 'land', 'abort'"
    ):
        replay_run(copy, tmp_path / "replayed2")
