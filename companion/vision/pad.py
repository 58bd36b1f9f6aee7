"""Nested ArUco landing pad (delivery section 4.2.1) and its true-scale rendering.

The delivery paper puts a small 0.09 m marker inside a large 0.8 m marker so that the pad is
seen from high up (large marker) and right down to touchdown (small marker). Both markers are
centred on the pad centre. The outer marker comes from a 5x5 dictionary and the inner one from a
4x4 dictionary: with two dictionaries the detector finds both; with one dictionary the outer
marker is lost once the inner one decodes (see tests/vision/test_pad.py, which measures it).

Frames: the pad frame is the OpenCV ArUco marker frame — x right, y up (as the printed marker is
viewed), z out of the pad plane (up, towards a camera above it) — with its origin at the pad
centre. Marker corners are listed in ArUco order: top-left, top-right, bottom-right, bottom-left,
which is the order ``cv2.SOLVEPNP_IPPE_SQUARE`` expects.

The rendered inner marker sits on a white quiet zone one inner-marker cell wide; with the default
outer id (0 in DICT_5X5_50) the central cell of the outer marker is white, so the quiet zone only
grazes neighbouring cells and the outer marker still decodes.
"""

from __future__ import annotations

import logging
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
INCH_M = 0.0254

_DICT_NAMES = {n for n in dir(cv2.aruco) if n.startswith("DICT_")}


class PadConfigError(ValueError):
    """A pad layout file (or value) is invalid; the message names file, key, value, rule."""


def aruco_dictionary(name: str) -> Any:
    """``cv2.aruco.Dictionary`` for a name such as ``"DICT_5X5_50"``."""
    if name not in _DICT_NAMES:
        raise ValueError(f"unknown ArUco dictionary {name!r}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def square_corners(size_m: float, center_xy: tuple[float, float] = (0.0, 0.0)) -> FloatArray:
    """Corners (4, 3) of a square marker in ArUco order (TL, TR, BR, BL), z = 0, y up."""
    h = size_m / 2.0
    cx, cy = center_xy
    return np.array([[cx - h, cy + h, 0.0], [cx + h, cy + h, 0.0], [cx + h, cy - h, 0.0], [cx - h, cy - h, 0.0]])


@dataclass(frozen=True)
class PadLayout:
    """A nested two-marker pad; both markers centred at the pad origin (delivery 4.2.1)."""

    outer_id: int = 0
    outer_dict: str = "DICT_5X5_50"
    outer_size_m: float = 0.8
    inner_id: int = 0
    inner_dict: str = "DICT_4X4_50"
    inner_size_m: float = 0.09
    pad_size_m: float = 1.0

    def __post_init__(self) -> None:
        for name in ("outer_size_m", "inner_size_m", "pad_size_m"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"pad {name} = {v!r}: must be a finite number > 0")
        for which in ("outer", "inner"):
            dname = getattr(self, f"{which}_dict")
            if dname not in _DICT_NAMES:
                raise ValueError(f"pad {which}_dict = {dname!r}: unknown ArUco dictionary")
            mid = getattr(self, f"{which}_id")
            n = aruco_dictionary(dname).bytesList.shape[0]
            if isinstance(mid, bool) or not isinstance(mid, int) or not 0 <= mid < n:
                raise ValueError(f"pad {which}_id = {mid!r}: must be an integer in [0, {n}) for {dname}")
        if self.outer_size_m > self.pad_size_m:
            raise ValueError(f"pad outer_size_m = {self.outer_size_m}: must be <= pad_size_m = {self.pad_size_m}")
        if self.inner_quiet_size_m >= self.outer_size_m * 0.5:
            raise ValueError(
                f"pad inner_size_m = {self.inner_size_m}: with its quiet zone it must be smaller than "
                f"half the outer marker ({self.outer_size_m / 2} m)"
            )
        if self.outer_dict == self.inner_dict and self.outer_id == self.inner_id:
            raise ValueError("pad: inner and outer markers must differ (same dictionary and id)")

    # ------------------------------------------------------------------ geometry
    @property
    def inner_cell_m(self) -> float:
        return self.inner_size_m / (aruco_dictionary(self.inner_dict).markerSize + 2)

    @property
    def outer_cell_m(self) -> float:
        return self.outer_size_m / (aruco_dictionary(self.outer_dict).markerSize + 2)

    @property
    def inner_quiet_size_m(self) -> float:
        """Side of the white square around the inner marker (one inner cell each side)."""
        return self.inner_size_m + 2.0 * self.inner_cell_m

    @property
    def outer_corners(self) -> FloatArray:
        """Outer marker corners (4, 3) in the pad frame, ArUco order."""
        return square_corners(self.outer_size_m)

    @property
    def inner_corners(self) -> FloatArray:
        """Inner marker corners (4, 3) in the pad frame, ArUco order."""
        return square_corners(self.inner_size_m)

    @property
    def same_dictionary(self) -> bool:
        return self.outer_dict == self.inner_dict

    def marker_size_m(self, which: str) -> float:
        if which == "outer":
            return self.outer_size_m
        if which == "inner":
            return self.inner_size_m
        raise ValueError(f"marker {which!r}: must be 'outer' or 'inner'")

    def marker_corners(self, which: str) -> FloatArray:
        return square_corners(self.marker_size_m(which))


# ---------------------------------------------------------------------------- rendering


def render_pad_px(layout: PadLayout, side_px: int) -> NDArray[np.uint8]:
    """The pad as a square greyscale image ``side_px`` wide (white background, markers centred)."""
    side = int(side_px)
    if side < 16:
        raise ValueError(f"pad image side {side_px!r} px: must be >= 16")
    px_per_m = side / layout.pad_size_m
    img = np.full((side, side), 255, np.uint8)

    def place(block: Any) -> None:
        n = block.shape[0]
        o = (side - n) // 2
        img[o : o + n, o : o + n] = block

    outer_px = round(layout.outer_size_m * px_per_m)
    place(cv2.aruco.generateImageMarker(aruco_dictionary(layout.outer_dict), layout.outer_id, outer_px))
    quiet_px = round(layout.inner_quiet_size_m * px_per_m)
    place(np.full((quiet_px, quiet_px), 255, np.uint8))
    inner_px = round(layout.inner_size_m * px_per_m)
    if inner_px < aruco_dictionary(layout.inner_dict).markerSize + 2:
        log.warning("pad image %d px: the inner marker is only %d px wide", side, inner_px)
    place(cv2.aruco.generateImageMarker(aruco_dictionary(layout.inner_dict), layout.inner_id, inner_px))
    return img


def pad_side_px(layout: PadLayout, dpi: float) -> int:
    """Pixels across the pad at ``dpi`` at true scale: metres / 0.0254 * dpi."""
    if not (math.isfinite(dpi) and dpi > 0):
        raise ValueError(f"dpi = {dpi!r}: must be > 0")
    return round(layout.pad_size_m / INCH_M * dpi)


def render_pad(layout: PadLayout, dpi: float = 150.0) -> NDArray[np.uint8]:
    """The pad at true scale for printing: ``pad_size_m / 0.0254 * dpi`` pixels across."""
    return render_pad_px(layout, pad_side_px(layout, dpi))


def max_png_dpi(layout: PadLayout) -> float:
    """Highest ``dpi`` whose PNG stays within Pillow's decompression-bomb limit
    (``PIL.Image.MAX_IMAGE_PIXELS``, 89.5 Mpx): larger images make Pillow-based viewers and
    print tools warn or refuse to open them."""
    from PIL import Image

    limit = Image.MAX_IMAGE_PIXELS or 89_478_485
    return math.floor(math.sqrt(limit) * INCH_M / layout.pad_size_m)


def save_pad_png(layout: PadLayout, path: str | Path, dpi: float = 150.0) -> Path:
    """Render the pad at true scale and write it as PNG with its DPI in the file (pHYs), so a
    print dialog at 100 % scale prints it at ``pad_size_m``. ``dpi`` above :func:`max_png_dpi`
    is refused (the image would exceed Pillow's decompression-bomb limit)."""
    from PIL import Image

    p = Path(path)
    if p.suffix.lower() != ".png":
        raise ValueError(f"pad output {p}: must end in .png")
    top = max_png_dpi(layout)
    if not (math.isfinite(dpi) and 0 < dpi <= top):
        raise ValueError(
            f"dpi = {dpi!r}: must be > 0 and <= {top} for a {layout.pad_size_m:g} m pad "
            "(larger PNGs exceed Pillow's decompression-bomb limit; print the PDF instead)"
        )
    img = render_pad(layout, dpi)
    p.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img, mode="L").save(p, format="PNG", dpi=(dpi, dpi))
    log.info("wrote pad %s: %d px at %.0f dpi = %.3f m", p, img.shape[0], dpi, layout.pad_size_m)
    return p


#: a PDF page side is at most 14 400 user units (200 in = 5.08 m; PDF 1.7 annex C)
PDF_MAX_PAGE_M = 200.0 * INCH_M


def marker_cells_m(layout: PadLayout, which: str) -> list[tuple[float, float, float, float]]:
    """The black cells of one marker as rectangles ``(x0, y0, x1, y1)`` in the pad frame
    (metres, origin at the pad centre, x right, y up); a row's adjacent cells are merged."""
    dname = layout.outer_dict if which == "outer" else layout.inner_dict
    mid = layout.outer_id if which == "outer" else layout.inner_id
    dictionary = aruco_dictionary(dname)
    n = dictionary.markerSize + 2  # data bits and the one-cell black border
    bits = cv2.aruco.generateImageMarker(dictionary, mid, n)  # one pixel per cell
    size = layout.marker_size_m(which)
    cell = size / n
    half = size / 2.0
    rects = []
    for r in range(n):
        y1 = half - r * cell
        c = 0
        while c < n:
            if bits[r, c] >= 128:
                c += 1
                continue
            start = c
            while c < n and bits[r, c] < 128:
                c += 1
            rects.append((-half + start * cell, y1 - cell, -half + c * cell, y1))
    return rects


def save_pad_pdf(layout: PadLayout, path: str | Path) -> Path:
    """Write the pad as a one-page vector PDF whose page is the pad at true size
    (``pad_size_m`` square) with the markers drawn as filled paths (matplotlib's PDF backend);
    printed at 100 % scale (no "fit to page") the markers measure exactly their configured size."""
    from matplotlib.backends.backend_pdf import FigureCanvasPdf
    from matplotlib.figure import Figure
    from matplotlib.patches import PathPatch, Rectangle
    from matplotlib.path import Path as MplPath

    p = Path(path)
    if p.suffix.lower() != ".pdf":
        raise ValueError(f"pad output {p}: must end in .pdf")
    if layout.pad_size_m > PDF_MAX_PAGE_M:
        raise ValueError(
            f"pad_size_m = {layout.pad_size_m:g}: a PDF page is at most {PDF_MAX_PAGE_M:.2f} m wide; "
            "print the pad in tiles from the PNG"
        )
    side_in = layout.pad_size_m / INCH_M
    fig = Figure(figsize=(side_in, side_in), facecolor="white")
    FigureCanvasPdf(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    half = layout.pad_size_m / 2.0
    ax.set_xlim(-half, half)
    ax.set_ylim(-half, half)
    ax.set_axis_off()

    square = [int(MplPath.MOVETO), *[int(MplPath.LINETO)] * 3, int(MplPath.CLOSEPOLY)]

    def black(which: str) -> PathPatch:
        verts: list[tuple[float, float]] = []
        codes: list[int] = []
        for x0, y0, x1, y1 in marker_cells_m(layout, which):
            verts += [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
            codes += square
        # one compound path per marker: same-orientation squares, non-zero fill, no seams between cells
        return PathPatch(MplPath(verts, codes), facecolor="black", edgecolor="none", linewidth=0, antialiased=False)

    q = layout.inner_quiet_size_m / 2.0
    ax.add_patch(black("outer"))
    ax.add_patch(Rectangle((-q, -q), 2 * q, 2 * q, facecolor="white", edgecolor="none", linewidth=0))
    ax.add_patch(black("inner"))
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, format="pdf", metadata={"Title": f"companion landing pad {layout.pad_size_m:g} m"})
    log.info("wrote pad %s: %.1f x %.1f pt = %.3f m", p, side_in * 72, side_in * 72, layout.pad_size_m)
    return p


# ---------------------------------------------------------------------------- TOML

_PAD_KEYS = ("outer_id", "outer_dict", "outer_size_m", "inner_id", "inner_dict", "inner_size_m", "pad_size_m")


def _pad_error(path: Path | str, key: str, value: Any, rule: str) -> PadConfigError:
    return PadConfigError(f"{path}: key '{key}' = {value!r}: {rule}")


def pad_from_mapping(data: dict[str, Any], source: Path | str = "<pad>") -> PadLayout:
    """Validate a ``[pad]`` table; errors name source, key, value and rule."""
    unknown = sorted(set(data) - set(_PAD_KEYS))
    if unknown:
        k = unknown[0]
        raise _pad_error(source, f"pad.{k}", data[k], f"unknown key (allowed: {list(_PAD_KEYS)})")
    for k, v in data.items():
        if k.endswith("_id") and (isinstance(v, bool) or not isinstance(v, int) or v < 0):
            raise _pad_error(source, f"pad.{k}", v, "must be a non-negative integer")
        if k.endswith("_dict") and (not isinstance(v, str) or v not in _DICT_NAMES):
            raise _pad_error(source, f"pad.{k}", v, "must be a cv2.aruco dictionary name, e.g. 'DICT_5X5_50'")
        if k.endswith("_m") and (
            isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0
        ):
            raise _pad_error(source, f"pad.{k}", v, "must be a number > 0 (metres)")
    kwargs: dict[str, Any] = {k: (float(v) if k.endswith("_m") else v) for k, v in data.items()}
    try:
        return PadLayout(**kwargs)
    except ValueError as exc:
        raise PadConfigError(f"{source}: [pad] {exc}") from exc


def load_pad(path: str | Path) -> PadLayout:
    """Read a pad layout TOML file with a ``[pad]`` table (params/pad_*.toml)."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            doc = tomllib.load(fh)
    except OSError as exc:
        raise PadConfigError(f"{p}: cannot read pad file: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise PadConfigError(f"{p}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise PadConfigError(f"{p}: not UTF-8 text, as TOML must be: {exc}") from None
    unknown = sorted(set(doc) - {"pad"})
    if unknown:
        raise _pad_error(p, unknown[0], doc[unknown[0]], "unknown table/key (allowed: pad)")
    if not isinstance(doc.get("pad"), dict):
        raise _pad_error(p, "pad", doc.get("pad"), "a [pad] table is required")
    return pad_from_mapping(doc["pad"], p)


def pad_to_toml(layout: PadLayout) -> str:
    lines = [
        "# Nested ArUco landing pad (delivery section 4.2.1), companion.vision.pad.PadLayout.",
        "[pad]",
        f"outer_id = {layout.outer_id}",
        f'outer_dict = "{layout.outer_dict}"',
        f"outer_size_m = {float(layout.outer_size_m)!r}",
        f"inner_id = {layout.inner_id}",
        f'inner_dict = "{layout.inner_dict}"',
        f"inner_size_m = {float(layout.inner_size_m)!r}",
        f"pad_size_m = {float(layout.pad_size_m)!r}",
    ]
    return "\n".join(lines) + "\n"


def save_pad(layout: PadLayout, path: str | Path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(pad_to_toml(layout))
    return p
