"""A run folder on a full or read-only disk: refused at start-up (exit 2, one line naming the
folder and the reason), and a disk that fills in flight costs the flight nothing: it completes,
its result is printed, and the exit code (8) and one line say the logs were cut. Real file
systems: a tmpfs mounted for the test (``tests/tmpfs.py``)."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from companion.cli import exits
from companion.cli.args import FLIGHT_LOGS_MIN_BYTES
from companion.cli.main import main
from companion.config import shipped_params_path

from ..tmpfs import fill, mounted_tmpfs


def _one_line(err: str, command: str) -> str:
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"companion {command}: "), err
    return lines[0]


def test_demo_on_a_disk_without_room_for_a_flight_is_refused(tmp_path: Path, capsys):
    with mounted_tmpfs(tmp_path / "disk", "2m") as d:
        run = d / "run"
        assert main(["demo", "--quiet", "--out", str(run)]) == exits.BAD_INPUT
        line = _one_line(capsys.readouterr().err, "demo")
        assert line.startswith(f"companion demo: --out {run}: 2.1 MB free, a run needs at least 67 MB; ")
        assert line.endswith("free some space or pass another --out")
        assert list(run.iterdir()) == []  # the probe is gone, nothing flew


@pytest.mark.parametrize(
    "command",
    [["demo", "--quiet"], ["campaign", "landing", "--n", "1", "--quiet"]],
    ids=["demo", "campaign landing"],
)
def test_a_read_only_out_is_refused_at_start(tmp_path: Path, capsys, command: list[str]):
    with mounted_tmpfs(tmp_path / "ro", "1m", read_only=True) as d:
        assert main([*command, "--out", str(d)]) == exits.BAD_INPUT
        line = _one_line(capsys.readouterr().err, command[0])
        assert line.endswith(f"--out {d}: cannot write there: Read-only file system; pass another --out")
        assert main([*command, "--out", str(d / "run")]) == exits.BAD_INPUT  # a folder to create there
        line = _one_line(capsys.readouterr().err, command[0])
        assert line.endswith(f"--out {d / 'run'}: cannot create the folder: Read-only file system; pass another --out")


def test_dart_json_on_a_read_only_disk_is_refused_at_start(tmp_path: Path, capsys):
    with mounted_tmpfs(tmp_path / "ro", "1m", read_only=True) as d:
        assert main(["campaign", "dart", "--n", "1", "--quiet", "--json", str(d / "dart.json")]) == exits.BAD_INPUT
        line = _one_line(capsys.readouterr().err, "campaign")
        assert line.endswith(f"--json {d}: cannot write there: Read-only file system; pass another --json")


def test_fly_on_a_read_only_out_is_refused_before_the_link_opens(tmp_path: Path):
    params = tmp_path / "vehicle.toml"
    params.write_text(
        'autopilot = "px4"\nconnection = "udpin://127.0.0.1:9"\n'
        "[runtime]\nconnect_timeout_s = 30.0\n[landing]\nfusion = false\n[telemetry]\nenabled = false\n"
    )
    with mounted_tmpfs(tmp_path / "ro", "1m", read_only=True) as d:
        t0 = time.monotonic()
        proc = subprocess.run(
            [sys.executable, "-m", "companion", "fly", "--params", str(params), "--out", str(d)],
            capture_output=True,
            text=True,
            timeout=60.0,
            cwd=tmp_path,
        )
        assert proc.returncode == exits.BAD_INPUT, proc.stderr
        assert time.monotonic() - t0 < 25.0  # not the 30 s connect timeout: refused before the link
        line = _one_line(proc.stderr, "fly")
        assert line == f"companion fly: --out {d}: cannot write there: Read-only file system; pass another --out"


def _fill_once_flying(run: Path, disk: Path, done: threading.Event) -> None:
    """Another writer fills the disk once the flight's logs are being written."""
    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline:
        f = run / "flight.csv"
        if f.exists() and f.stat().st_size > 10_000:
            fill(disk)
            break
        time.sleep(0.01)
    done.set()


@pytest.mark.flight
def test_a_disk_that_fills_in_flight_costs_the_flight_nothing(tmp_path: Path, capsys):
    size_mb = FLIGHT_LOGS_MIN_BYTES // 2**20 + 16  # room for the start-up check, not for the logs
    with mounted_tmpfs(tmp_path / "disk", f"{size_mb}m") as d:
        run = d / "run"
        filled = threading.Event()
        filler = threading.Thread(target=_fill_once_flying, args=(run, d, filled), daemon=True)
        filler.start()
        params = str(shipped_params_path("sitl_short.toml"))
        code = main(["demo", "--params", params, "--quiet", "--out", str(run)])
        filler.join(5.0)
        captured = capsys.readouterr()
        assert filled.is_set()
        # the flight completed and its result is printed; the exit code and a line say the logs are cut
        assert "DELIVERED, returned home" in captured.out and "landing error on the pad" in captured.out
        assert code == exits.LOGS_INCOMPLETE == 8, captured.err
        assert "logs incomplete: disk full (" in captured.out
        assert "Traceback" not in captured.out + captured.err
        # the end of the flight still fits (the room kept for it): run.json closed, naming the fault
        summary = json.loads((run / "summary.json").read_text())
        assert summary["delivered"] and summary["returned"]
        meta = json.loads((run / "run.json").read_text())
        assert meta["closed"] and meta["storage_faults"]["flight.mcap"] == "DISK_FULL"
        assert set(meta["storage_faults"].values()) == {"DISK_FULL"}
        assert not (run / ".room").exists()
        # report and replay go on with what the folder holds
        (d / "ballast").unlink()
        assert main(["report", str(run), "--out", str(tmp_path / "figs")]) == 0
        assert "figure(s) written" in capsys.readouterr().out
        assert main(["replay", str(run), "--out", str(tmp_path / "replay")]) in (0, 1)
        assert "stopped in flight (disk full)" in capsys.readouterr().out


def test_fly_that_delivered_with_its_logs_cut_exits_8(tmp_path: Path, monkeypatch, capsys):
    """The flight is the backend's (here a stand-in that writes a real log on a disk it fills);
    what fly decides from the logs is its own: delivered, logs cut -> exit 8 and one line."""
    from companion.cli import fly as commands
    from companion.delivery.mission import MissionSummary
    from companion.flightlog.csvlog import CsvLog

    async def run_delivery(config, autopilot, timeout_s, run_dir, landing=None, before_flight=None, on_tick=None):
        lg = CsvLog(run_dir / "flight.csv", ("time_s", "x_m"))
        fill(run_dir.parent)
        for i in range(20000):  # well past the file's last page
            lg.write((float(i), 1.0 / 3.0))
        lg.close()
        return MissionSummary(delivered=True, returned=True)

    monkeypatch.setattr(commands, "make_autopilot", lambda config, **kw: object())
    monkeypatch.setattr(commands, "run_delivery", run_delivery)
    params = str(shipped_params_path("ardupilot_quad.toml"))
    with mounted_tmpfs(tmp_path / "disk", f"{FLIGHT_LOGS_MIN_BYTES // 2**20 + 16}m") as d:
        run = d / "run"
        code = main(["fly", "--params", params, "--out", str(run), "--no-preflight", "--json"])
        captured = capsys.readouterr()
        assert code == exits.LOGS_INCOMPLETE, captured.err
        assert '"delivered": true' in captured.out
        line = next(x for x in captured.err.splitlines() if x.startswith("companion fly: "))
        assert line.startswith("companion fly: logs incomplete: disk full (flight.csv ") and line.endswith(
            f"{run} holds the flight up to where they stopped"
        )
