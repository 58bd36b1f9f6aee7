"""Hardware-in-the-loop with a recorded camera, through the commands a team runs:

1. ``companion calibrate`` on chessboard images (rendered here by the simulator's camera);
2. ``companion demo --record-camera cam.avi``: one simulated flight, its landing camera's frames
   recorded with their exposure times (cam.avi.csv);
3. ``companion demo --camera-file cam.avi --camera-calibration cam.toml``: the same flight with
   the camera replaced by the recording, played through the OpenCV camera plugin at its own
   frame times on the simulated clock, into the detector and the EKF.

UWB is off, and the GPS is 2 m biased with the pad lying 0.7 m from its configured place, so a
landing on the pad can only come from the camera (GPS-only lands ~2 m off, test_delivery_sim).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import pytest

from companion.cli.main import main
from companion.config import shipped_params_path
from companion.vision.camera import CalibrationPattern, load_camera, load_default_camera
from companion_sitl.camera_targets import chessboard_views

SCENARIO = ["--seed", "3", "--gps-bias", "2,0", "--pad-offset", "0.4,-0.6", "--quiet"]


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.flight
def test_recorded_camera_flies_the_landing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 1. intrinsics from chessboard images rendered through the simulator's camera (seeded)
    pattern = "chessboard:9x6:0.025"
    boards = []
    for i, img in enumerate(chessboard_views(load_default_camera(), CalibrationPattern.parse(pattern), 12, seed=3)):
        boards.append(tmp_path / f"board{i:02d}.png")
        cv2.imwrite(str(boards[-1]), img)
    calib = tmp_path / "cam.toml"
    assert main(["calibrate", *map(str, boards), "--pattern", pattern, "--out", str(calib)]) == 0
    truth = load_default_camera()
    cal = load_camera(calib)
    assert abs(cal.fx - truth.fx) < 0.01 * truth.fx and abs(cal.cx - truth.cx) < 3.0

    params = ["--params", str(shipped_params_path("delivery_paper.toml")), "--params", str(tmp_path / "no_uwb.toml")]
    (tmp_path / "no_uwb.toml").write_text("[landing]\nuse_uwb = false\n")

    # 2. record the landing camera of one simulated flight
    video = tmp_path / "cam.avi"
    rec_dir = tmp_path / "rec"
    assert main(["demo", *params, *SCENARIO, "--out", str(rec_dir), "--record-camera", str(video)]) == 0
    times = [float(r["time_s"]) for r in _rows(Path(f"{video}.csv"))]
    assert len(times) > 300
    cap = cv2.VideoCapture(str(video))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == len(times)
    cap.release()

    # 3. fly it again with the camera replaced by the recording
    play_dir = tmp_path / "play"
    play = ["--camera-file", str(video), "--camera-calibration", str(calib)]
    code = main(["demo", *params, *SCENARIO, "--out", str(play_dir), *play])
    capsys.readouterr()
    summary = json.loads((play_dir / "summary.json").read_text())
    assert code == 0 and summary["delivered"] and summary["returned"], summary
    assert summary["pad_landing_error_m"] < 0.15

    # the observations are the recording's frames, at the recording's exposure times
    obs = _rows(play_dir / "camera.csv")
    recorded = {round(t, 6) for t in times}
    assert len(obs) > 300
    assert all(round(float(o["time_s"]), 6) in recorded for o in obs)
    detected = [o for o in obs if o["ambiguous"] in ("0", "False", "false")]
    assert len(detected) > 200
    fused = max(int(r["markers_used"]) for r in _rows(play_dir / "ekf.csv"))
    assert fused > 200


def test_camera_file_options_are_checked_before_flight(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--quiet", "--camera-times", "t.csv"]) == 2
    assert "--camera-times needs --camera-file VIDEO" in capsys.readouterr().err
    assert main(["demo", "--quiet", "--camera-file", str(tmp_path / "none.avi")]) == 2
    assert "none.avi: no such file" in capsys.readouterr().err
    (tmp_path / "v.avi").write_bytes(b"not a video")
    assert main(["demo", "--quiet", "--camera-file", str(tmp_path / "v.avi"), "--gps-only"]) == 2
    assert "need the fused landing with the camera" in capsys.readouterr().err
    assert main(["demo", "--quiet", "--out", str(tmp_path / "r"), "--camera-file", str(tmp_path / "v.avi")]) == 2
    assert "cannot open the video file" in capsys.readouterr().err
    assert main(["demo", "--quiet", "--camera-file", "a.avi", "--record-camera", "b.avi"]) == 2
    assert "not both" in capsys.readouterr().err
