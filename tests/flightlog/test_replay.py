"""`companion replay`: a recorded flight replayed through the same core code gives the same
estimates and guidance bit for bit; a changed input changes them."""

from __future__ import annotations

import asyncio
import csv
import json
import math
import os
import signal

import pytest

from companion.cli.main import main
from companion.delivery.replay import replay_run
from companion.flightlog.reader import LogFormatError, Table

from .conftest import short_config

pytestmark = pytest.mark.flight


def _edit_cell(path, row, column, fn):
    rows = list(csv.reader(path.open(newline="")))
    i = rows[0].index(column)
    rows[row][i] = fn(rows[row][i])
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)


def test_replay_of_the_demo_is_identical_bit_for_bit(demo_run, tmp_path):
    r = replay_run(demo_run, tmp_path / "replayed")
    assert r.identical, "\n".join(r.lines())
    assert r.missing_seq == 0 and r.ticks == r.streams["guidance.csv"].recorded_rows > 500
    assert r.streams["ekf.csv"].recorded_rows == r.streams["ekf.csv"].replayed_rows > 500
    # the replayed estimates are written, same columns, same text
    assert (tmp_path / "replayed" / "ekf.csv").read_text() == (demo_run / "ekf.csv").read_text()
    assert (tmp_path / "replayed" / "guidance.csv").read_text() == (demo_run / "guidance.csv").read_text()


def test_a_changed_camera_observation_changes_the_replayed_estimates(run_copy):
    cam = Table(run_copy / "camera.csv")
    assert len(cam) > 20
    _edit_cell(run_copy / "camera.csv", len(cam) // 2, "t_x_m", lambda v: repr(float(v) + 0.002))
    r = replay_run(run_copy)
    assert not r.identical
    ekf = r.streams["ekf.csv"]
    assert ekf.differing_rows > 0 and ekf.max_abs_diff["north_m"] > 0 and "ekf.csv seq" in ekf.first_difference
    assert r.streams["ekf.csv"].recorded_rows == r.streams["ekf.csv"].replayed_rows


def test_a_changed_autopilot_sample_changes_the_guidance(run_copy):
    # a GPS position before the fusion starts: the mission plans from it and flies on it
    _edit_cell(run_copy / "ap_position.csv", 200, "north_m", lambda v: repr(float(v) + 0.01))
    r = replay_run(run_copy)
    assert not r.identical and r.streams["guidance.csv"].max_abs_diff.get("est_north_m", 0.0) > 0


def test_cli_replay_exit_codes(run_copy, capsys):
    assert main(["replay", str(run_copy)]) == 0
    out = capsys.readouterr().out
    assert "IDENTICAL" in out and "ekf.csv" in out
    _edit_cell(run_copy / "uwb.csv", 5, "x_m", lambda v: repr(float(v) + 0.05))
    assert main(["replay", str(run_copy), "--out", str(run_copy / "again")]) == 1
    assert "NOT IDENTICAL" in capsys.readouterr().out


def test_malformed_logs_are_named_by_file_line_and_column(run_copy, demo_run, capsys):
    _edit_cell(run_copy / "ap_attitude.csv", 7, "yaw_rad", lambda v: "abc")
    with pytest.raises(LogFormatError, match=r"ap_attitude\.csv: line 8, column 'yaw_rad': 'abc' is not a valid float"):
        replay_run(run_copy)
    assert main(["replay", str(run_copy)]) == 2
    assert "ap_attitude.csv: line 8, column 'yaw_rad'" in capsys.readouterr().err
    (run_copy / "ap_attitude.csv").write_bytes((demo_run / "ap_attitude.csv").read_bytes())
    rows = list(csv.reader((run_copy / "uwb.csv").open(newline="")))
    del rows[0][rows[0].index("pdop")]
    with (run_copy / "uwb.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    with pytest.raises(LogFormatError, match=r"uwb\.csv: line 1: missing column\(s\) \['pdop'\]"):
        replay_run(run_copy)


def test_not_a_run_folder(tmp_path):
    with pytest.raises(LogFormatError, match=r"run\.json: file not found"):
        replay_run(tmp_path)
    (tmp_path / "run.json").write_text('{"format": "something/9"}')
    with pytest.raises(LogFormatError, match=r"format 'something/9'"):
        replay_run(tmp_path)


def test_fly_logs_an_operator_ctrl_c_and_replays_it(tmp_path):
    """`companion fly`'s runner (run_delivery) on the simulator under virtual time: SIGINT at
    t = 15 s aborts (hold, then land); the logs are closed and the replay, abort included, is exact."""
    from companion.cli.fly import run_delivery
    from companion_sitl.autopilot import SimAutopilot
    from companion_sitl.clock import run_virtual

    config = short_config()
    config = config.model_copy(update={"telemetry": config.telemetry.model_copy(update={"enabled": False})})
    run = tmp_path / "fly"

    async def flight():
        asyncio.get_running_loop().call_later(15.0, os.kill, os.getpid(), signal.SIGINT)
        return await run_delivery(config, SimAutopilot(config.sim), timeout_s=300.0, run_dir=run)

    summary = run_virtual(flight())
    assert not summary.delivered and "operator abort (SIGINT)" in summary.failure
    meta = json.loads((run / "run.json").read_text())
    assert meta["closed"] and meta["landing"] is False
    cmds = Table(run / "commands.csv")
    assert (
        len(cmds) == 1 and cmds.text(0, "source") == "operator" and cmds.text(0, "detail") == "operator abort (SIGINT)"
    )
    assert 15.0 <= cmds.value(0, "time_s") <= 15.1
    r = replay_run(run)
    assert r.identical, "\n".join(r.lines())
    assert r.streams["ekf.csv"].recorded_rows == 0  # GPS-only: no fusion on this vehicle
    kinds = [Table(run / "events.csv").text(k, "kind") for k in range(len(Table(run / "events.csv")))]
    assert "abort" in kinds


def test_replay_of_a_flight_on_anchors_at_one_height_is_identical(tmp_path):
    """uwb.csv carries HDOP/VDOP and vertical_weak: the replayed EKF weights the weak vertical as
    the flight did (without them the replay would fuse the fixes isotropically and differ)."""
    from companion.config import shipped_params_path
    from companion_lab.demo import run_demo
    from companion_sitl.params import load_simulated_config

    config = load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "sim": {"seed": 3, "gps_bias_m": [1.0, -0.5, 0.0], "pad_offset_m": [0.3, -0.2]},
            "landing": {"use_camera": False, "uwb_anchors": "uwb_anchors_one_height.toml"},
        },
    )
    run = tmp_path / "run"
    r = run_demo(config, run_dir=run)
    assert r.delivered and r.returned, r.failure
    uwb = Table(run / "uwb.csv")
    assert len(uwb) > 50
    assert all(uwb.value(k, "vertical_weak", bool) for k in range(len(uwb)))
    assert all(uwb.value(k, "vdop") > 0.0 for k in range(len(uwb)))
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())
    # and the recorded weights matter: flipping the flag changes the replayed estimates
    rows = list(csv.reader((run / "uwb.csv").open(newline="")))
    i = rows[0].index("vertical_weak")
    for row in rows[1:]:
        row[i] = "0"
    with (run / "uwb.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    assert not replay_run(run, tmp_path / "replayed2").identical


def test_replay_of_a_flight_with_every_shell_input_is_identical(tmp_path):
    """Everything the shell hands the core besides samples, fixes, results and commands is
    recorded and replayed: the velocity-bias correction of every setpoint (PX4 SIH's tuning), the
    fence's verdict reached before the first tick (commands.csv, source go_no_go) and the wind
    estimate each tick handed the wind go/no-go (wind.csv)."""
    from companion.config import shipped_params_path
    from companion.geometry.earth import GeoPoint, ned_to_geo
    from companion_lab.demo import run_demo
    from companion_sitl.params import load_simulated_config

    home = GeoPoint(-19.869, -43.9638, 850.0)  # sitl_short.toml's [sim.home]
    corners = [ned_to_geo(home, n, e, 0.0) for n, e in ((-50, -50), (100, -50), (100, 100), (-50, 100))]
    config = load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "sim": {"seed": 3, "profile": "px4-sih"},
            "mission": {"velocity_bias_tau_s": 1.0},
            "fence": {"enabled": True, "inclusion": [{"vertices_deg": [[p.lat_deg, p.lon_deg] for p in corners]}]},
            "go_no_go": {"wind_limit_m_s": 12.0},
        },
    )
    run = tmp_path / "run"
    r = run_demo(config, run_dir=run)
    assert r.delivered and r.returned, r.failure
    cmds = Table(run / "commands.csv")
    assert [(cmds.text(k, "source"), cmds.text(k, "kind")) for k in range(len(cmds))] == [("go_no_go", "go")]
    wind = Table(run / "wind.csv")
    assert len(wind) == len(Table(run / "guidance.csv"))
    # the autopilot's estimate (none at the first ticks; px4-sih has no wind: 0 m/s), refreshed
    stamps = [wind.value(k, "wind_time_s") for k in range(len(wind))]
    assert sum(math.isfinite(t) for t in stamps) > 0.9 * len(stamps) and len(set(stamps)) > len(stamps) / 20
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())
    assert rep.streams["ekf.csv"].recorded_rows > 500

    # each of them matters: without the correction the setpoints differ (up to ~0.8 m/s on
    # px4-sih), without the fence's verdict the events do, and without the wind the mission
    # waits on the ground for an estimate
    meta = json.loads((run / "run.json").read_text())
    meta["config"]["mission"]["velocity_bias_tau_s"] = 0.0
    (run / "run.json").write_text(json.dumps(meta))
    r1 = replay_run(run, tmp_path / "r1")
    assert r1.streams["guidance.csv"].max_abs_diff.get("sp_north_m_s", 0.0) > 0.05, "\n".join(r1.lines())
    meta["config"]["mission"]["velocity_bias_tau_s"] = 1.0
    (run / "run.json").write_text(json.dumps(meta))
    rows = list(csv.reader((run / "commands.csv").open(newline="")))
    with (run / "commands.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(rows[:1])
    r2 = replay_run(run, tmp_path / "r2")
    assert r2.streams["events.csv"].text_diffs and r2.missing_seq == 1, "\n".join(r2.lines())
    with (run / "commands.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    # a log from before wind.csv (not in run.json's streams; the MCAP holds it too, so it goes)
    (run / "wind.csv").unlink()
    (run / "flight.mcap").unlink()
    del meta["streams"]["wind.csv"]
    (run / "run.json").write_text(json.dumps(meta))
    r3 = replay_run(run, tmp_path / "r3")
    assert not r3.identical and any("wind.csv missing" in n for n in r3.notes), "\n".join(r3.lines())


def test_a_go_no_go_verdict_of_an_unknown_kind_is_named(run_copy):
    with (run_copy / "commands.csv").open("a", newline="") as fh:
        csv.writer(fh).writerow([0.0, 10**9, "go_no_go", "maybe", "fence", ""])
    with pytest.raises(LogFormatError, match=r"commands\.csv: line 2, column 'kind': 'maybe' is not one of 'go'"):
        replay_run(run_copy)


def test_replay_measures_the_pad_lock_when_the_flight_had_pad_sensors(tmp_path):
    """The pad lock the mission is handed comes from the kit the shell flew with (run.json
    pad_sensors), not from what the configuration would build: here a kit with camera and UWB on
    a configuration that names neither, with the pad-lock policy on (the test harnesses of the
    real firmwares hand the shell such a kit)."""
    from companion.delivery.shell import DeliveryShell
    from companion.flightlog.recorder import FlightRecorder
    from companion_lab.demo import true_pad_ned
    from companion_sitl.autopilot import SimAutopilot
    from companion_sitl.clock import run_virtual
    from companion_sitl.landing_sensors import sim_landing_kit
    from companion_sitl.vehicle import SimVehicle

    with_sensors = short_config(gps_bias_m=[1.0, -0.5, 0.0], pad_offset_m=[0.3, -0.2])
    lc = with_sensors.landing
    policy = lc.policy.model_copy(update={"require_pad_lock": True})
    config = with_sensors.model_copy(
        update={"landing": lc.model_copy(update={"use_camera": False, "use_uwb": False, "policy": policy})}
    )
    run = tmp_path / "run"

    async def flight():
        vehicle = SimVehicle(config.sim)
        pad = true_pad_ned(config)
        vehicle.set_pad_truth(*pad)
        ap = SimAutopilot(config.sim, vehicle)
        kit = sim_landing_kit(with_sensors, vehicle, pad)
        with FlightRecorder(run, config, mcap=False) as rec:
            try:
                return await DeliveryShell(config, ap, landing=kit, recorder=rec).run(timeout_s=300.0)
            finally:
                await ap.close()

    summary = run_virtual(flight())
    assert summary.delivered and summary.returned, summary.failure
    assert json.loads((run / "run.json").read_text())["pad_sensors"] is True
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())
    # without the key (a log from before it) the replay goes by the configuration: no sensors,
    # no pad lock, so the policy's fallback takes over where the flight had its lock
    meta = json.loads((run / "run.json").read_text())
    del meta["pad_sensors"]
    (run / "run.json").write_text(json.dumps(meta))
    assert not replay_run(run, tmp_path / "replayed2").identical


def test_replay_of_the_bias_measured_against_the_fused_position_is_identical(tmp_path):
    """PX4 SIH's landing tuning: the velocity bias measured against the fused position, the
    EKF's input corrected by it ([mission] velocity_bias_source, [landing] ekf_velocity_bias_tau_s)
    and the attitude's tilt taken out on the level pad ([landing] ekf_level_pad) are replayed bit
    for bit from run.json; without either correction the EKF's estimates differ."""
    from companion.config import shipped_params_path
    from companion_lab.demo import run_demo
    from companion_sitl.params import load_simulated_config

    config = load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "sim": {"seed": 3, "profile": "px4-sih"},
            "mission": {"velocity_bias_tau_s": 1.0, "velocity_bias_source": "fusion"},
            "landing": {"ekf_velocity_bias_tau_s": 1.0, "ekf_level_pad": True},
        },
    )
    run = tmp_path / "run"
    r = run_demo(config, run_dir=run)
    assert r.delivered and r.returned, r.failure
    meta = json.loads((run / "run.json").read_text())
    assert meta["fusion"]["velocity_bias_tau_s"] == 1.0 and meta["fusion"]["velocity_bias_source"] == "fusion"
    assert meta["fusion"]["level_pad"] is True
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())
    meta["fusion"]["velocity_bias_tau_s"] = 0.0
    (run / "run.json").write_text(json.dumps(meta))
    r1 = replay_run(run, tmp_path / "r1")
    assert r1.streams["ekf.csv"].max_abs_diff.get("east_m_s", 0.0) > 0.01, "\n".join(r1.lines())
    meta["fusion"]["velocity_bias_tau_s"] = 1.0
    del meta["fusion"]["level_pad"]
    (run / "run.json").write_text(json.dumps(meta))
    r2 = replay_run(run, tmp_path / "r2")
    # the px4-sih profile's attitude error is 1-2 deg: the EKF's attitude follows it without the level pad
    assert r2.streams["ekf.csv"].max_abs_diff.get("roll_rad", 0.0) > 0.005, "\n".join(r2.lines())


def test_a_folder_with_an_empty_summary_replays(run_copy, capsys):
    # replay does not need summary.json: an empty one (a disk full at the flight's end) changes nothing
    (run_copy / "summary.json").write_text("")
    assert main(["replay", str(run_copy)]) == 0
    assert "IDENTICAL" in capsys.readouterr().out
