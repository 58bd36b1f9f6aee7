"""The `companion pad` and `companion calibrate` subcommands (wired into the CLI elsewhere)."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.cli.vision import register
from companion.vision.camera import CalibrationPattern, CameraModel, load_camera
from companion.vision.pad import PadLayout, pad_side_px, save_pad
from companion_sitl.camera_targets import chessboard_views


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="companion")
    register(parser.add_subparsers(dest="command", required=True))
    return parser


def test_pad_command_writes_true_scale_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "pad.png"
    args = _parser().parse_args(["pad", "--out", str(out), "--dpi", "40"])
    assert args.func(args) == 0
    img = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (pad_side_px(PadLayout(), 40),) * 2
    assert "800 mm" in capsys.readouterr().out


def test_pad_command_with_params_and_bad_params(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    lay = PadLayout(outer_size_m=0.5, inner_size_m=0.06, pad_size_m=0.6)
    params = save_pad(lay, tmp_path / "pad_small.toml")
    out = tmp_path / "small.png"
    args = _parser().parse_args(["pad", "--out", str(out), "--dpi", "30", "--params", str(params)])
    assert args.func(args) == 0
    assert cv2.imread(str(out), cv2.IMREAD_GRAYSCALE).shape[0] == pad_side_px(lay, 30)
    bad = tmp_path / "pad_bad.toml"
    bad.write_text("[pad]\nouter_size_m = 'big'\n")
    args = _parser().parse_args(["pad", "--out", str(out), "--params", str(bad)])
    assert args.func(args) == 2
    assert "pad.outer_size_m" in capsys.readouterr().err


def test_pad_command_writes_pdf_and_png_by_default(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    args = _parser().parse_args(["pad", "--dpi", "20"])
    assert args.func(args) == 0
    assert (tmp_path / "pad.pdf").read_bytes().startswith(b"%PDF")
    png = cv2.imread(str(tmp_path / "pad.png"), cv2.IMREAD_GRAYSCALE)
    assert png is not None and png.shape[0] == pad_side_px(PadLayout(), 20)
    out = capsys.readouterr().out
    assert "page 1000 x 1000 mm" in out and "800 mm" in out
    args = _parser().parse_args(["pad", "--out", "pad.svg"])
    assert args.func(args) == 2
    assert "--out pad.svg: must end in .pdf (vector, true size) or .png" in capsys.readouterr().err


def _chessboard_images(folder: Path, n: int) -> list[str]:
    """``n`` PNG views of a 9x6 chessboard (25 mm squares) through a known camera, their paths."""
    truth = CameraModel(640, 480, 510.0, 510.0, 320.0, 240.0, dist=(0.08, -0.1, 0.0, 0.0, 0.0))
    names = []
    for i, img in enumerate(chessboard_views(truth, CalibrationPattern.parse("chessboard:9x6:0.025"), n, seed=9)):
        p = folder / f"view{i}.png"
        cv2.imwrite(str(p), img)
        names.append(str(p))
    return names


def test_calibrate_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    names = _chessboard_images(tmp_path, 7)
    out = tmp_path / "camera_test.toml"
    args = _parser().parse_args(["calibrate", *names, "--pattern", "chessboard:9x6:0.025", "--out", str(out)])
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert "reprojection error (RMS)" in text
    cam = load_camera(out)
    assert cam.fx == pytest.approx(510.0, rel=0.02)
    assert "rms_px" in out.read_text()


def test_calibrate_command_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = _parser().parse_args(
        [
            "calibrate",
            str(tmp_path / "missing.png"),
            "--pattern",
            "chessboard:9x6:0.025",
            "--out",
            str(tmp_path / "c.toml"),
        ]
    )
    assert args.func(args) == 2 and "companion calibrate: cannot read image" in capsys.readouterr().err
    args = _parser().parse_args(["calibrate", "x.png", "--pattern", "rings:3", "--out", "c.toml"])
    assert args.func(args) == 2 and "pattern" in capsys.readouterr().err


def test_calibrate_names_the_images_it_skipped_and_a_wrong_size_is_bad_input_as_a_missing_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    names = _chessboard_images(tmp_path, 6)
    blank = tmp_path / "lens_cap.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    out = tmp_path / "camera_test.toml"
    argv = ["calibrate", *names[:3], str(blank), *names[3:], "--pattern", "chessboard:9x6:0.025", "--out", str(out)]
    assert _parser().parse_args(argv).func(_parser().parse_args(argv)) == 0
    err = capsys.readouterr().err
    assert f"skipped {blank}: no 9x6 chessboard found" in err and "used 6 of 7 images" in err, err
    assert "calibrated from 6 of 7 images" in out.read_text()
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.full((240, 320), 128, np.uint8))
    argv = ["calibrate", *names[:2], str(small), "--pattern", "chessboard:9x6:0.025", "--out", str(out)]
    assert _parser().parse_args(argv).func(_parser().parse_args(argv)) == 2  # as a missing image: bad input
    assert f"image {small} is 320x240, expected 640x480" in capsys.readouterr().err
