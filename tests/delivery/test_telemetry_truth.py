"""Ground telemetry tells the truth: a fused delivery published over real Zenoh (loopback) to a
recording ground station; every field of every message received is checked against the run
folder's flight logs (flight.csv, ekf.csv, camera.csv, uwb.csv, truth.csv)."""

from __future__ import annotations

import bisect
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest

from companion.delivery.telemetry import FRESH_S
from companion.flightlog.reader import read_columns
from companion.telemetry.ground import GroundStation
from companion.telemetry.loopback import free_tcp_port, loopback_settings
from companion.vision.pad import PadLayout
from companion_lab.demo import run_demo

pytestmark = pytest.mark.flight


def _config(mav, zenoh_config: Path):  # type: ignore[no-untyped-def]
    """The short scenario fused, on a biased GPS and a displaced pad, publishing over ``zenoh_config``."""
    return mav.shipped_config(
        sim={"seed": 4, "gps_bias_m": [1.0, -0.5, 0.0], "pad_offset_m": [0.3, 0.2]},
        landing={"fusion": True},
        telemetry={"zenoh_config": str(zenoh_config)},
    )


def _messages(rec: Path, topic: str) -> list[dict]:
    lines = (rec / "sitl1" / f"{topic}.jsonl").read_text().splitlines()
    return [json.loads(line)["env"]["msg"] for line in lines if line]


def _f(col: list[str]) -> np.ndarray:
    return np.array([float(v) if v not in ("", "nan") else math.nan for v in col])


@pytest.fixture(scope="module")
def flight(tmp_path_factory, mav):
    tmp = tmp_path_factory.mktemp("telemetry_truth")
    port = free_tcp_port()
    run = tmp / "run"
    with GroundStation(loopback_settings(listen_port=port), out_dir=tmp / "rec") as ground:
        r = run_demo(_config(mav, mav.connect_only_zenoh(tmp, port)), run_dir=run, telemetry=True)
        end = time.monotonic() + 5.0
        while time.monotonic() < end and not ("sitl1" in ground.snapshot() and not ground.snapshot()["sitl1"].alive):
            time.sleep(0.01)
        ground.flush()
        row = ground.snapshot()["sitl1"]
    assert r.delivered and r.returned, r.failure
    return r, run, tmp / "rec", row


def test_state_fields_come_from_the_tick_they_were_published_at(flight):
    _r, run, rec, _row = flight
    fl = read_columns(run / "flight.csv")
    by_est = {}
    for i in range(len(fl["time_s"])):
        key = tuple(float(fl[k][i]) for k in ("est_north_m", "est_east_m", "est_down_m"))
        by_est.setdefault(key, []).append((fl["mode"][i], fl["armed"][i] == "1"))
    states = _messages(rec, "state")
    assert len(states) > 20
    for m in states:
        rows = by_est.get((m["north_m"], m["east_m"], m["down_m"]))
        assert rows, f"state at t={m['time_s']} matches no guidance tick's estimate"
        assert (m["mode"], m["armed"]) in rows, (m["time_s"], m["mode"], m["armed"], rows)
        for age in ("status_age_s", "gps_age_s", "global_position_age_s"):
            assert m[age] is not None and 0.0 <= m[age] < 1.0, (age, m[age])
    assert states[-1]["armed"] is False  # the last state is the disarmed vehicle at home


def test_mission_fields_match_the_flight_log(mav, flight):
    _r, run, rec, _row = flight
    fl = read_columns(run / "flight.csv")
    ticks = {float(t): i for i, t in enumerate(fl["time_s"])}
    meta = json.loads((run / "run.json").read_text())
    conf_pad = meta["mission"]["pad_ned_m"]
    speeds = mav.short_config().mission.sector_speed_m_s
    gl = read_columns(run / "guidance.csv")
    guidance_at = {float(t): i for i, t in enumerate(gl["time_s"])}
    senses: dict[str, set[int]] = {}
    distances = 0
    for m in _messages(rec, "mission"):
        if m["event"] is not None:
            continue
        i = ticks[m["time_s"]]
        assert m["phase"] == fl["phase"][i]
        assert (m["sector"] or 0) == int(fl["sector"][i] or 0)
        v = float(fl["lyapunov_m2"][i])
        assert (m["lyapunov_v_m2"] is None) == (not math.isfinite(v))
        if m["lyapunov_v_m2"] is not None:
            assert m["lyapunov_v_m2"] == v
        # the field's v_r and s of that tick: absent / 0 outside the vector field
        if m["speed_ref_m_s"] is None:
            assert m["sense"] == 0
        else:
            assert m["sense"] in (1, -1) and m["sector"] is not None
            assert 0.0 < m["speed_ref_m_s"] <= speeds[m["sector"] - 1] + 1e-9
            senses.setdefault(m["phase"], set()).add(m["sense"])
        # distance to the configured pad from the estimate flown on at that tick
        g = guidance_at[m["time_s"]]  # the estimate the mission flew on at that tick (fused near the pad)
        est = (float(gl["est_north_m"][g]), float(gl["est_east_m"][g]))
        if not math.isfinite(est[0]):  # no estimate at that tick: absent
            assert m["distance_to_pad_m"] is None
        else:
            d = math.hypot(est[0] - conf_pad[0], est[1] - conf_pad[1])
            assert m["distance_to_pad_m"] == pytest.approx(d, abs=1e-9), (m["phase"], m["time_s"])
            distances += 1
    assert distances > 5
    assert senses["outbound"] == {1} and senses["inbound"] == {-1}, senses


def test_health_carries_the_process_cpu_and_no_heartbeat_in_the_embedded_simulator(flight):
    _r, _run, rec, _row = flight
    health = _messages(rec, "health")
    assert len(health) >= 3
    # the first health message has no interval to measure over (cpu_pct None), but health is sent
    # keep-newest at 1 Hz of wall time while the embedded demo runs ~20x real time, so the first can
    # be replaced by the next before the worker sends it
    first = health[0]["cpu_pct"]
    assert first is None or first > 0.0, first
    cpu = [m["cpu_pct"] for m in health[1:]]
    assert all(c is not None and c > 0.0 for c in cpu), cpu
    # the embedded simulator has no HEARTBEAT: the field is absent, not a made-up age
    assert all(m["heartbeat_age_s"] is None for m in health)


def test_landing_fields_match_the_sensor_logs_and_truth(flight):
    r, run, rec, row = flight
    landings = _messages(rec, "landing")
    assert len(landings) > 10
    cam = read_columns(run / "camera.csv")
    cam_t = _f(cam["time_s"])
    uwb = read_columns(run / "uwb.csv")
    uwb_t = _f(uwb["time_s"])
    ekf = read_columns(run / "ekf.csv")
    ekf_at = {float(t): i for i, t in enumerate(ekf["tick_s"])}
    fl = read_columns(run / "flight.csv")
    phase_at = dict(zip(map(float, fl["time_s"]), fl["phase"], strict=True))
    truth = read_columns(run / "truth.csv")
    tt = _f(truth["time_s"])
    tn, te, td = (_f(truth[k]) for k in ("true_north_m", "true_east_m", "true_down_m"))
    summary = json.loads((run / "summary.json").read_text())
    pad_n, pad_e = summary["true_pad_ned_m"]
    meta = json.loads((run / "run.json").read_text())
    conf_pad = meta["mission"]["pad_ned_m"]  # where the fused frame puts the pad
    layout = PadLayout()
    ids = {"outer": layout.outer_id, "inner": layout.inner_id}
    sightings = errors = fixes = 0
    for m in landings:
        now = m["time_s"]
        age = m["observation_age_s"]
        assert m["pad_visible"] == (age is not None and age < FRESH_S)
        if age is None:
            assert m["pad_rel_north_m"] is None and m["markers_seen"] == [] and m["marker_names"] == []
        else:
            sightings += 1
            t_obs = now - age
            j = int(np.argmin(np.abs(cam_t - t_obs)))
            assert abs(cam_t[j] - t_obs) < 1e-6, "the observation's exposure is in camera.csv"
            assert m["marker_names"] == cam["markers"][j].split(), (m["marker_names"], cam["markers"][j])
            assert m["markers_seen"] == [ids[n] for n in m["marker_names"]]
            # the pad relative to the vehicle at exposure, against truth
            k = bisect.bisect_left(tt, t_obs)
            k = min(max(k, 1), len(tt) - 1)
            w = (t_obs - tt[k - 1]) / (tt[k] - tt[k - 1])
            pos = [a[k - 1] + w * (a[k] - a[k - 1]) for a in (tn, te, td)]
            rel_true = (pad_n - pos[0], pad_e - pos[1], 0.0 - pos[2])
            rel = (m["pad_rel_north_m"], m["pad_rel_east_m"], m["pad_rel_down_m"])
            assert math.dist(rel, rel_true) < 0.25, (now, rel, rel_true)
        i = ekf_at.get(now)
        if m["landing_error_m"] is None:
            assert i is None or ekf["xi"][i] == "0" or phase_at[now] not in ("outbound", "landing_pad", "release")
        else:
            errors += 1
            assert i is not None and ekf["xi"][i] == "1"
            assert phase_at[now] in ("outbound", "landing_pad", "release")
            est = math.hypot(float(ekf["north_m"][i]) - conf_pad[0], float(ekf["east_m"][i]) - conf_pad[1])
            assert m["landing_error_m"] == pytest.approx(est, abs=1e-9)
        ua = m["uwb_fix_age_s"]
        assert m["uwb_fix_ok"] == (ua is not None and ua < FRESH_S)
        if ua is None:
            assert m["uwb_anchors_used"] == 0 and m["uwb_residual_m"] is None
        else:
            fixes += 1
            j = int(np.argmin(np.abs(uwb_t - (now - ua))))
            assert abs(uwb_t[j] - (now - ua)) < 1e-6, "the fix is in uwb.csv"
            assert m["uwb_residual_m"] == float(uwb["residual_rms_m"][j])
            assert m["uwb_anchors_used"] == len(uwb["anchors_used"][j].split())
    assert sightings and errors and fixes
    # the last estimated landing error, on the pad, is the true one (the pad moved, GPS biased)
    on_pad = [m for m in landings if m["landing_error_m"] is not None]
    assert abs(on_pad[-1]["landing_error_m"] - r.pad_landing_error_m) < 0.15
    assert row.landing_error_m is not None


def test_estimate_fields_match_the_ekf_log(flight):
    _r, run, rec, _row = flight
    ekf = read_columns(run / "ekf.csv")
    # several updates can share a time (an autopilot sample, then a marker exposed at that instant);
    # a message is one of the states logged at its time, all its fields from the same row
    rows: dict[float, list[int]] = {}
    for i, t in enumerate(ekf["time_s"]):
        rows.setdefault(float(t), []).append(i)
    states = ("north_m", "east_m", "down_m", "roll_rad", "pitch_rad", "yaw_rad")
    biases = {"gps_bias_north_m": "bias_north_m", "gps_bias_east_m": "bias_east_m", "gps_bias_down_m": "bias_down_m"}
    gyro = ("gyro_bias_x_rad_s", "gyro_bias_y_rad_s", "gyro_bias_z_rad_s")
    var_cols = [h for h in ekf if h.startswith("var_")]
    estimates = _messages(rec, "estimate")
    assert len(estimates) > 10
    for m in estimates:
        assert m["source"] == "ekf"
        at = rows[m["time_s"]]
        i = min(at, key=lambda j: abs(m["north_m"] - float(ekf["north_m"][j])))
        for k in states + gyro:
            assert m[k] == pytest.approx(float(ekf[k][i]), abs=1e-12), k
        for k, col in biases.items():
            assert m[k] == pytest.approx(float(ekf[col][i]), abs=1e-12), k
        assert m["covariance_diag"] == pytest.approx([float(ekf[c][i]) for c in var_cols], rel=1e-12)
        # every accepted marker and UWB fix is counted among the fused measurements
        assert m["fused_count"] >= int(ekf["markers_used"][i]) + int(ekf["uwb_used"][i])


def test_log_messages_are_the_autopilot_status_texts(flight):
    _r, run, rec, _row = flight
    texts = read_columns(run / "ap_statustext.csv")
    logged = list(zip(map(float, texts["time_s"]), map(int, texts["severity"]), texts["text"], strict=True))
    published = [(m["time_s"], m["severity"], m["text"]) for m in _messages(rec, "log") if m["source"] == "autopilot"]
    assert published and published == logged  # never dropped, in order


def test_health_and_the_ground_row_of_a_finished_vehicle(flight):
    _r, run, rec, row = flight
    fl = read_columns(run / "flight.csv")
    ticks = {float(t) for t in fl["time_s"]}
    health = _messages(rec, "health")
    assert health
    for m in health:
        assert m["time_s"] in ticks and m["link_ok"] is True
    # the vehicle is gone: the ground keeps its history but shows it as such
    assert not row.alive and row.phase is not None and row.phase.value == "done"
    assert row.armed is False
