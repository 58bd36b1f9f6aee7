"""CLI of the vision layer: ``companion pad`` and ``companion calibrate``.

``register(subparsers)`` adds them to the application's argparse subparsers; each handler takes
the parsed args and returns an exit code.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

import cv2

from companion.cli.args import Once
from companion.vision.camera import CalibrationPattern, calibrate, save_camera
from companion.vision.pad import PadLayout, load_pad, pad_side_px, save_pad_pdf, save_pad_png

log = logging.getLogger(__name__)


def _cmd_pad(args: argparse.Namespace) -> int:
    outs: list[Path] = args.out or [Path("pad.pdf"), Path("pad.png")]
    try:
        layout = load_pad(args.params) if args.params else PadLayout()
        for out in outs:
            if out.suffix.lower() not in (".pdf", ".png"):
                raise ValueError(f"--out {out}: must end in .pdf (vector, true size) or .png (raster at --dpi)")
        written = []
        for out in outs:
            if out.suffix.lower() == ".pdf":
                save_pad_pdf(layout, out)
                side_mm = layout.pad_size_m * 1000
                written.append(f"{out}: vector PDF, page {side_mm:.0f} x {side_mm:.0f} mm")
            else:
                save_pad_png(layout, out, args.dpi)
                side = pad_side_px(layout, args.dpi)
                written.append(f"{out}: {side}x{side} px at {args.dpi:g} dpi (stored in the file)")
    except (ValueError, OSError) as exc:
        print(f"companion pad: {exc}", file=sys.stderr)
        return 2
    for line in written:
        print(f"wrote {line}")
    print(
        f"pad {layout.pad_size_m:g} m; outer {layout.outer_dict} id {layout.outer_id} {layout.outer_size_m:g} m, "
        f"inner {layout.inner_dict} id {layout.inner_id} {layout.inner_size_m:g} m. "
        "Print at 100 % scale (no fit to page) and check the outer marker measures "
        f"{layout.outer_size_m * 1000:.0f} mm."
    )
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    def bad(msg: str) -> int:
        print(f"companion calibrate: {msg}", file=sys.stderr)
        return 2

    try:
        pattern = CalibrationPattern.parse(args.pattern)
    except ValueError as exc:
        return bad(str(exc))
    images: list[Any] = []
    for name in args.images:  # every image is bad input alike: unreadable, or not the first's size
        img = cv2.imread(str(name), cv2.IMREAD_GRAYSCALE)
        if img is None:
            return bad(f"cannot read image {name} (missing, or not an image OpenCV reads)")
        if images and img.shape != images[0].shape:
            h, w = img.shape[:2]
            h0, w0 = images[0].shape[:2]
            return bad(f"image {name} is {w}x{h}, expected {w0}x{h0} as {args.images[0]} (one camera, one size)")
        images.append(img)
    skipped: list[tuple[int, str]] = []
    try:
        cam, rms = calibrate(
            images, pattern, kind=args.model, min_views=args.min_views, on_skip=lambda i, why: skipped.append((i, why))
        )
    except ValueError as exc:
        _say_skipped(args.images, skipped)
        print(f"companion calibrate: {exc}", file=sys.stderr)
        return 1
    _say_skipped(args.images, skipped)
    out = save_camera(
        cam,
        args.out,
        rms_px=rms,
        n_images=len(images) - len(skipped),
        note=f"calibrated from {len(images) - len(skipped)} of {len(images)} images, pattern {args.pattern}",
    )
    print(f"reprojection error (RMS): {rms:.3f} px")
    print(
        f"fx {cam.fx:.2f} fy {cam.fy:.2f} cx {cam.cx:.2f} cy {cam.cy:.2f} "
        f"dist {[round(d, 5) for d in cam.dist]} k_ud {cam.k_ud:.5f} ({cam.kind})"
    )
    print(f"wrote {out}")
    if rms > 1.0:
        print("warning: RMS above 1 px; check the images (focus, motion blur, pattern flatness)")
    return 0


def _say_skipped(names: list[Any], skipped: list[tuple[int, str]]) -> None:
    """Each image the target was not found in, by name, and how many were used."""
    for i, why in skipped:
        print(f"skipped {names[i]}: {why}", file=sys.stderr)
    if skipped:
        print(f"used {len(names) - len(skipped)} of {len(names)} images", file=sys.stderr)


def register(subparsers: Any) -> None:
    """Add the ``pad`` and ``calibrate`` subcommands to an argparse subparsers object."""
    p = subparsers.add_parser("pad", help="write the nested ArUco landing pad at true size (vector PDF, PNG)")
    p.add_argument(
        "--out",
        type=Path,
        action="append",
        help="output file, .pdf (vector, page = pad size) or .png (at --dpi, DPI stored); repeatable "
        "(default: pad.pdf and pad.png)",
    )
    p.add_argument(
        "--dpi", type=float, default=150.0, help="PNG resolution, at most ~240 for a 1 m pad (default: %(default)s)"
    )
    p.add_argument(
        "--params",
        action=Once,
        type=Path,
        default=None,
        help="pad layout TOML with a [pad] table (default: the delivery paper's pad)",
    )
    p.set_defaults(func=_cmd_pad)

    c = subparsers.add_parser("calibrate", help="calibrate a camera from chessboard/ChArUco images")
    c.add_argument("images", nargs="+", type=Path, help="image files (>= 5 views)")
    c.add_argument(
        "--pattern",
        required=True,
        help="chessboard:COLSxROWS:SQUARE_M (inner corners) or charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT] (squares)",
    )
    c.add_argument("--out", type=Path, required=True, help="output TOML, e.g. params/camera_x.toml")
    c.add_argument(
        "--model",
        choices=("opencv", "dart"),
        default="opencv",
        help="distortion model: OpenCV k1,k2,p1,p2,k3 or the Dart single coefficient",
    )
    c.add_argument("--min-views", type=int, default=5, help="minimum views with the pattern found")
    c.set_defaults(func=_cmd_calibrate)
