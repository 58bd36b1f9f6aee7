import json

import matplotlib.image as mpimg
import numpy as np
import pytest

from companion.cli.main import main
from companion.config import shipped_params_path


@pytest.mark.flight
def test_demo_writes_run_folder_and_plots(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["demo", "--out", str(out), "--quiet", "--seed", "2"]) == 0
    text = capsys.readouterr().out
    assert "DELIVERED, returned home" in text and "landing error on the pad" in text
    for name in ("flight.csv", "truth.csv", "events.csv", "summary.json", "path.png", "lyapunov.png"):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["delivered"] and summary["returned"] and summary["path"]["h_m"] == 45.0
    for png in ("path.png", "lyapunov.png"):
        img = mpimg.imread(out / png)
        assert img.shape[0] > 300 and img.shape[1] > 600
        assert np.std(img[..., :3]) > 0.05  # not a blank image
    header = (out / "flight.csv").read_text().splitlines()[0].split(",")
    assert header[0] == "time_s" and "est_north_m" in header and "sp_down_m_s" in header


def test_bad_params_file_exit_code_and_message(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[mission]\nheight_m = 10.0\narc_radius_m = 12.0\nwhat = 1\n")
    assert main(["demo", "--params", str(bad), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "mission.what" in err and "unknown key" in err
    bad.write_text("[mission]\nheight_m = 10.0\narc_radius_m = 12.0\n")
    assert main(["params", "check", str(bad)]) == 1
    err = capsys.readouterr().err
    assert str(bad) in err and "arc_radius_m (12.0) must be < height_m (10.0)" in err


def test_bad_gps_bias_option(capsys):
    assert main(["demo", "--gps-bias", "two", "--quiet"]) == 2
    assert "--gps-bias" in capsys.readouterr().err


@pytest.mark.parametrize("offset", ["0.4", "0.4,-0.6,1"])
def test_a_pad_offset_of_other_than_north_and_east_is_refused(offset, capsys, tmp_path):
    # it was taken as 0.4,0 (and the third number dropped) silently
    assert main(["demo", "--pad-offset", offset, "--quiet", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "--pad-offset" in err and "expected 2 components (north,east)" in err, err
    assert not (tmp_path / "run").exists()


def test_params_show_documents_units(capsys):
    assert main(["params", "show"]) == 0
    out = capsys.readouterr().out
    assert "mission.height_m = 45.0 [m]" in out and "sim.wind_speed_m_s" in out


def test_bench_estimation_prints_figures(capsys):
    assert main(["bench", "estimation", "--n", "200"]) == 0
    out = capsys.readouterr().out
    assert "madgwick_update_us" in out and "SCF-MF-3DOF.vision_us" in out


def test_vision_commands_are_wired(tmp_path, capsys):
    out = tmp_path / "pad.png"
    assert main(["pad", "--out", str(out), "--dpi", "30"]) == 0
    assert out.stat().st_size > 1000
    assert main(["bench", "vision", "--frames", "12"]) == 0
    assert "ours/raw" in capsys.readouterr().out


def test_bench_ekf_and_uwb_are_wired(capsys):
    assert main(["bench", "ekf", "--n", "50"]) == 0
    assert main(["bench", "uwb", "--n", "10"]) == 0
    out = capsys.readouterr().out
    assert "predict_us" in out and "update_aruco_us" in out


@pytest.mark.flight
def test_demo_over_mavlink_px4(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(
        [
            "demo",
            "--mavlink",
            "px4",
            "--params",
            str(shipped_params_path("sitl_short.toml")),
            "--quiet",
            "--out",
            str(out),
        ]
    )
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "DELIVERED, returned home" in text
    assert json.loads((out / "summary.json").read_text())["pad_landing_error_m"] < 1.0


@pytest.mark.flight
def test_bench_sim_reports_both_flights(capsys):
    assert main(["bench", "sim", "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    assert "GPS-only (simulator + guidance):" in out and "with camera rendering" in out


@pytest.mark.parametrize(
    "argv",
    [
        ["campaign", "landing", "--n", "0"],
        ["campaign", "landing", "--n", "-6"],
        ["campaign", "parity", "--autopilot", "px4", "--n", "0"],
        ["campaign", "dart", "--n", "0"],
        ["bench", "campaign", "--n", "0"],
        ["bench", "ekf", "--n", "0"],
        ["bench", "signing", "--n", "0"],
    ],
    ids=lambda a: " ".join(a),
)
def test_a_count_below_one_is_refused_before_anything_runs(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert f"argument --n: {argv[-1]}: need at least 1" in capsys.readouterr().err


@pytest.mark.parametrize("command", [["demo", "--quiet"], ["campaign", "landing", "--n", "1", "--quiet"]])
def test_an_out_that_cannot_be_a_folder_is_refused_before_the_flight(tmp_path, capsys, command):
    in_the_way = tmp_path / "a_file"
    in_the_way.write_text("not a folder")
    assert main([*command, "--out", str(in_the_way)]) == 2
    assert f"--out {in_the_way}: a file of that name is in the way" in capsys.readouterr().err
    assert main([*command, "--out", str(in_the_way / "run")]) == 2
    assert f"--out {in_the_way / 'run'}: cannot create the folder" in capsys.readouterr().err
    assert in_the_way.read_text() == "not a folder"


def test_bench_app_refuses_a_cap_with_real_time_threads(capsys):
    assert main(["bench", "app", "--cpu-cap", "pi4", "--realtime-priority", "5"]) == 2
    assert "--realtime-priority" in capsys.readouterr().err


def test_a_reader_that_closes_the_pipe_ends_the_command_quietly():
    import subprocess
    import sys

    cmd = [sys.executable, "-c", "import sys; from companion.cli.main import main; sys.exit(main())", "params", "show"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()  # as `| head -1`: one line read, then the pipe closed
    proc.stdout.close()
    err = proc.stderr.read().decode()
    # 1 once the pipe broke; 0 in the rare run where all 42 kB fitted the pipe before it closed
    assert proc.wait(timeout=60) in (0, 1) and first.startswith(b"#")
    assert err == "", err  # no BrokenPipeError traceback, no "Exception ignored" on the final flush


@pytest.mark.parametrize(
    "argv",
    [
        ["fly"],
        ["preflight"],
        ["signing", "push"],
        ["campaign", "landing"],
        ["campaign", "parity", "--autopilot", "px4"],
        ["dart"],
        ["campaign", "dart"],
        ["pad"],
    ],
)
def test_a_command_that_reads_one_parameter_file_refuses_two(argv, capsys):
    # `fly --params a --params b` flew b alone, silently; demo and bench app take overlays
    with pytest.raises(SystemExit) as exit_:
        main([*argv, "--params", "a.toml", "--params", "b.toml"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "--params given twice (a.toml, then b.toml)" in err, err


@pytest.mark.flight
def test_ctrl_c_in_the_demo_holds_lands_and_ends_with_the_summary_and_130(tmp_path):
    """As `fly` (docs/flying.md): the operator's abort is flown (hold, then land), the summary is
    printed, commands.csv holds the abort, exit 130. It ended at once with an empty commands.csv."""
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    code = (
        "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        "from companion.cli.main import main; sys.exit(main())"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "demo", "--quiet", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60.0
    while not (out / "events.csv").exists() or "takeoff" not in (out / "events.csv").read_text():
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120.0)
    assert proc.returncode == 130, (stdout[-2000:], stderr[-2000:])
    assert "NOT DELIVERED  aborted: operator abort (SIGINT)" in stdout and "flight time" in stdout, stdout
    rows = (out / "commands.csv").read_text().splitlines()
    assert any(",operator,abort,operator abort (SIGINT)," in r for r in rows), rows
    summary = json.loads((out / "summary.json").read_text())
    assert summary["failure_kind"] == "operator_abort" and not summary["delivered"]
    phases = [r.split(",")[3] for r in (out / "events.csv").read_text().splitlines()[1:] if ",phase," in r]
    assert phases[-3:] == ["abort_hold", "abort_land", "failed"], phases  # held, landed, ended


@pytest.mark.flight
def test_the_demo_says_what_its_folder_keeps_and_no_mcap_keeps_less(tmp_path, capsys):
    short = str(shipped_params_path("sitl_short.toml"))
    assert main(["demo", "--quiet", "--params", short, "--out", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    assert "run folder size" in out and "of it flight.mcap" in out and "--no-mcap leaves it out" in out, out
    assert main(["demo", "--quiet", "--no-mcap", "--params", short, "--out", str(tmp_path / "b")]) == 0
    assert "no flight.mcap (--no-mcap)" in capsys.readouterr().out
    assert (tmp_path / "a" / "flight.mcap").exists() and not (tmp_path / "b" / "flight.mcap").exists()
    size = {d: sum(f.stat().st_size for f in (tmp_path / d).iterdir()) for d in ("a", "b")}
    assert size["b"] < size["a"] / 2, size
    # the rest of the folder is the same flight
    assert (tmp_path / "a" / "events.csv").read_bytes() == (tmp_path / "b" / "events.csv").read_bytes()
