"""Re-render the committed detection fixture (run by hand: python tests/vision/make_fixtures.py).

The image and its ground truth are committed; tests only read them.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from companion.geometry import Transform
from companion.vision.camera import load_default_camera
from companion.vision.pad import PadLayout
from companion_sitl.camera import SimCameraConfig, SimulatedCamera

HERE = Path(__file__).resolve().parent / "fixtures"


def main() -> None:
    cam = load_default_camera()
    sim = SimulatedCamera(cam, PadLayout(), SimCameraConfig(noise_std=2.0), seed=7)
    frame = sim.capture(Transform.from_euler([0.25, -0.15, -2.5], 0.04, -0.03, 0.35), 1.0)
    HERE.mkdir(exist_ok=True)
    cv2.imwrite(str(HERE / "pad_2m5.png"), frame.image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    R, t = frame.T_camera_pad.R, frame.T_camera_pad.t
    rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in R)
    text = (
        "# Ground truth of pad_2m5.png (rendered by tests/vision/make_fixtures.py, seed 7):\n"
        "# nominal Pi camera v2 (params/camera_rpi_v2.toml), default pad, vehicle at 2.5 m.\n"
        f"R_camera_pad = [{rows}]\n"
        "t_camera_pad_m = [" + ", ".join(repr(float(v)) for v in t) + "]\n"
    )
    (HERE / "pad_2m5.toml").write_text(text)
    logging.getLogger(__name__).info("fixture truth t_camera_pad = %s", np.round(t, 4))


if __name__ == "__main__":
    main()
