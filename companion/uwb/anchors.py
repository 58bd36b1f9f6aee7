"""UWB anchor layouts (delivery section 4.2.2): which anchors exist and where they are.

Anchor positions are given in the *anchor frame* named by the layout (``frame``), normally the
pad frame: origin at the centre of the landing pad on the ground, x and y horizontal, z up (the
way Decawave DWM1001 anchors are configured, heights positive). The EKF receives fixes in this
frame together with ``T_world_anchorframe`` (see :func:`anchor_frame_to_ned`).

The base anchor is the anchor the TDoA differences are taken against: index 1 in delivery
eqs 2-4 (index 0 there is the tag).

Anchors at one height (four DWM1001 anchors on the ground or on tripods around the pad, the
paper's set-up) are *coplanar*: the ranges then fit the tag and its mirror image through the
anchors' plane equally well, and the tag's distance from that plane is only weakly observed.
Such a layout is accepted; ``tag_side`` ("above", the default, or "below") says on which side of
the plane the tag flies, and the multilateration picks that side and reports the weak vertical
(VDOP) so the EKF gets a larger vertical variance. With the side known, three anchors at one height
(not on a line) determine a TWR fix exactly, so a layout may have as few as 3 anchors
(:data:`MIN_COPLANAR_ANCHORS`; three anchors are always coplanar); anchors at different heights
need 4 (:data:`MIN_ANCHORS`). Only truly degenerate geometry is refused: fewer than 3 distinct
anchor positions, or anchors (nearly) on one line, where the tag's position around that line is
unobservable.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from companion.geometry import Transform

DEFAULT_LAYOUT_FILE = "uwb_anchors_pad.toml"
#: The Decawave DWM1001 working range the paper keeps between tag and anchors (delivery 4.2.2).
DWM1001_MAX_RANGE_M = 10.0
#: anchors at different heights (and any TDoA layout): x, y, z (and the TDoA offset) from 4 anchors
MIN_ANCHORS = 4
#: anchors at one height with a known ``tag_side``: TWR is exactly determined by 3 of them
MIN_COPLANAR_ANCHORS = 3
_ID_RE = re.compile(r"^[0-9A-Za-z_-]{1,16}$")
_MAX_COORD_M = 1000.0
#: the smallest singular value of the centred anchor positions: below this the anchors are
#: (nearly) coplanar; the tag's side of their plane comes from ``tag_side`` and its distance
#: from the plane is weakly observed.
MIN_NONCOPLANARITY_M = 0.1
#: the middle singular value: below this the anchors are (nearly) collinear -- refused.
MIN_NONCOLLINEARITY_M = 0.1
#: a coplanar layout's plane must be within 60 deg of horizontal (|normal_z| >= cos 60 deg) for
#: "above"/"below" to name a side of it.
MIN_PLANE_NORMAL_Z = 0.5
TAG_SIDES = ("above", "below")
_TOO_FEW_RULE = (
    f"at least {MIN_COPLANAR_ANCHORS} anchors at one height (with tag_side) or {MIN_ANCHORS} at different "
    "heights are needed (delivery 4.2.2)"
)


class AnchorLayoutError(ValueError):
    """An anchor layout is invalid; the message names the source, key, value and rule."""

    def __init__(self, source: str, key: str, value: object, rule: str) -> None:
        self.source = source
        self.key = key
        self.value = value
        self.rule = rule
        super().__init__(f"{source}: {key} = {value!r}: {rule}")


@dataclass(frozen=True)
class AnchorLayout:
    """Anchor ids and positions (metres, in ``frame``); immutable.

    ``base_anchor_id`` is the TDoA base anchor (delivery eq 2, index 1).
    """

    anchor_ids: tuple[str, ...]
    positions_m: tuple[tuple[float, float, float], ...]
    frame: str = "pad"
    base_anchor_id: str = ""
    max_range_m: float = DWM1001_MAX_RANGE_M
    tag_side: str = "above"

    def __post_init__(self) -> None:
        src = "AnchorLayout"
        if len(self.anchor_ids) != len(self.positions_m):
            raise AnchorLayoutError(
                src, "positions_m", len(self.positions_m), f"need one position per id ({len(self.anchor_ids)} ids)"
            )
        if len(self.anchor_ids) < MIN_COPLANAR_ANCHORS:
            raise AnchorLayoutError(src, "anchor_ids", self.anchor_ids, _TOO_FEW_RULE)
        if len(set(self.anchor_ids)) != len(self.anchor_ids):
            raise AnchorLayoutError(src, "anchor_ids", self.anchor_ids, "anchor ids must be unique")
        for i, aid in enumerate(self.anchor_ids):
            if not isinstance(aid, str) or not _ID_RE.match(aid):
                raise AnchorLayoutError(src, f"anchor_ids[{i}]", aid, "id must be 1-16 chars [0-9A-Za-z_-]")
        for i, pos in enumerate(self.positions_m):
            if len(pos) != 3 or not all(isinstance(c, float | int) and math.isfinite(c) for c in pos):
                raise AnchorLayoutError(src, f"positions_m[{i}]", pos, "need three finite numbers [x, y, z]")
            if max(abs(c) for c in pos) > _MAX_COORD_M:
                raise AnchorLayoutError(src, f"positions_m[{i}]", pos, f"coordinates must be within +-{_MAX_COORD_M} m")
        if not self.base_anchor_id:
            object.__setattr__(self, "base_anchor_id", self.anchor_ids[0])
        if self.base_anchor_id not in self.anchor_ids:
            raise AnchorLayoutError(src, "base_anchor_id", self.base_anchor_id, "must be one of the anchor ids")
        if not (math.isfinite(self.max_range_m) and 0.0 < self.max_range_m <= 100.0):
            raise AnchorLayoutError(src, "max_range_m", self.max_range_m, "must be in (0, 100] m")
        if self.tag_side not in TAG_SIDES:
            raise AnchorLayoutError(src, "tag_side", self.tag_side, f"must be one of {list(TAG_SIDES)}")
        problem = _geometry_problem(self.positions_array())
        if problem is not None:
            raise AnchorLayoutError(src, "positions_m", self.positions_m, problem)

    def positions_array(self) -> np.ndarray:
        """The positions as an (N, 3) float array (a fresh copy)."""
        return np.array(self.positions_m, dtype=float)

    def index_of(self, anchor_id: str) -> int:
        return self.anchor_ids.index(anchor_id)

    def position_of(self, anchor_id: str) -> np.ndarray:
        return np.array(self.positions_m[self.index_of(anchor_id)], dtype=float)

    def __contains__(self, anchor_id: object) -> bool:
        return anchor_id in self.anchor_ids

    @property
    def base_index(self) -> int:
        return self.index_of(self.base_anchor_id)

    @property
    def coplanar(self) -> bool:
        """All anchors (nearly) in one plane: the tag's distance from it is weakly observed."""
        return bool(_singular_values_m(self.positions_array())[2] < MIN_NONCOPLANARITY_M)

    @property
    def plane_point_m(self) -> np.ndarray:
        """The anchors' centroid (a point of their plane when :attr:`coplanar`)."""
        return self.positions_array().mean(axis=0)

    @property
    def tag_side_normal(self) -> np.ndarray:
        """Unit normal of the anchors' best-fit plane pointing to the tag's side (``tag_side``):
        +z-ish for "above", -z-ish for "below"."""
        return _plane_normal(self.positions_array(), self.tag_side)

    @staticmethod
    def from_mapping(data: Mapping[str, Any], source: str = "<mapping>") -> AnchorLayout:
        """Build a layout from parsed TOML; every error names source, key, value and rule."""
        allowed = {"frame", "base_anchor", "max_range_m", "tag_side", "anchors"}
        for key in data:
            if key not in allowed:
                raise AnchorLayoutError(source, key, data[key], f"unknown key (allowed: {sorted(allowed)})")
        frame = data.get("frame", "pad")
        if not isinstance(frame, str) or not frame:
            raise AnchorLayoutError(source, "frame", frame, "must be a non-empty string")
        max_range = data.get("max_range_m", DWM1001_MAX_RANGE_M)
        if isinstance(max_range, bool) or not isinstance(max_range, int | float):
            raise AnchorLayoutError(source, "max_range_m", max_range, "must be a number (metres)")
        if not (math.isfinite(max_range) and 0.0 < max_range <= 100.0):
            raise AnchorLayoutError(source, "max_range_m", max_range, "must be in (0, 100] m")
        tag_side = data.get("tag_side", "above")
        if tag_side not in TAG_SIDES:
            raise AnchorLayoutError(
                source, "tag_side", tag_side, f"must be one of {list(TAG_SIDES)} (the tag's side of coplanar anchors)"
            )
        anchors = data.get("anchors")
        if not isinstance(anchors, list) or len(anchors) < MIN_COPLANAR_ANCHORS:
            raise AnchorLayoutError(source, "anchors", anchors, f"need a list of [[anchors]] tables: {_TOO_FEW_RULE}")
        ids: list[str] = []
        positions: list[tuple[float, float, float]] = []
        for i, entry in enumerate(anchors):
            key = f"anchors[{i}]"
            if not isinstance(entry, dict):
                raise AnchorLayoutError(source, key, entry, "must be a table with id and position_m")
            for k in entry:
                if k not in ("id", "position_m"):
                    raise AnchorLayoutError(source, f"{key}.{k}", entry[k], "unknown key (allowed: id, position_m)")
            aid = entry.get("id")
            if not isinstance(aid, str) or not _ID_RE.match(aid):
                raise AnchorLayoutError(source, f"{key}.id", aid, "must be a string of 1-16 chars [0-9A-Za-z_-]")
            if aid in ids:
                raise AnchorLayoutError(source, f"{key}.id", aid, "duplicate anchor id")
            pos = entry.get("position_m")
            if (
                not isinstance(pos, list)
                or len(pos) != 3
                or not all(isinstance(c, int | float) and not isinstance(c, bool) for c in pos)
                or not all(math.isfinite(c) for c in pos)
            ):
                raise AnchorLayoutError(
                    source, f"{key}.position_m", pos, "must be [x, y, z], three finite numbers in metres"
                )
            if max(abs(c) for c in pos) > _MAX_COORD_M:
                raise AnchorLayoutError(
                    source, f"{key}.position_m", pos, f"coordinates must be within +-{_MAX_COORD_M} m"
                )
            ids.append(aid)
            positions.append((float(pos[0]), float(pos[1]), float(pos[2])))
        base = data.get("base_anchor", ids[0])
        if base not in ids:
            raise AnchorLayoutError(source, "base_anchor", base, f"must be one of the anchor ids {ids}")
        problem = _geometry_problem(np.array(positions))
        if problem is not None:
            raise AnchorLayoutError(source, "anchors.position_m", positions, problem)
        return AnchorLayout(tuple(ids), tuple(positions), frame, base, float(max_range), str(tag_side))

    @staticmethod
    def from_toml(path: str | Path) -> AnchorLayout:
        p = Path(path)
        try:
            with p.open("rb") as fh:
                data = tomllib.load(fh)
        except OSError as exc:
            raise AnchorLayoutError(str(p), "<file>", str(p), f"cannot read: {exc}") from exc
        except tomllib.TOMLDecodeError as exc:
            raise AnchorLayoutError(str(p), "<file>", str(p), f"invalid TOML: {exc}") from exc
        except UnicodeDecodeError as exc:
            raise AnchorLayoutError(str(p), "<file>", str(p), f"not UTF-8 text, as TOML must be: {exc}") from None
        return AnchorLayout.from_mapping(data, source=str(p))


def load_anchor_layout(path: str | Path | None = None) -> AnchorLayout:
    """Load a layout from ``path``, or the packaged ``params/uwb_anchors_pad.toml``."""
    if path is not None and Path(path).exists():
        return AnchorLayout.from_toml(path)
    name = DEFAULT_LAYOUT_FILE if path is None else str(path)
    ref = resources.files("companion_params").joinpath(name)
    with resources.as_file(ref) as real:
        return AnchorLayout.from_toml(real)


def _singular_values_m(positions: np.ndarray) -> np.ndarray:
    """The three singular values of the centred anchor positions (metres, descending)."""
    centred = positions - positions.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    return np.concatenate([sv, np.zeros(3 - len(sv))]) if len(sv) < 3 else sv


def _plane_normal(positions: np.ndarray, side: str) -> np.ndarray:
    centred = positions - positions.mean(axis=0)
    n = np.linalg.svd(centred)[2][-1]
    if n[2] < 0.0:
        n = -n
    return n if side == "above" else -n


def _geometry_problem(positions: np.ndarray) -> str | None:
    """Why these anchors cannot fix a tag (None: they can; coplanar is allowed, see module doc)."""
    distinct = len({tuple(np.round(p, 3)) for p in positions})
    if distinct < 3:
        return f"only {distinct} distinct anchor positions; at least 3 not on one line are needed"
    sv = _singular_values_m(positions)
    if sv[1] < MIN_NONCOLLINEARITY_M:
        return (
            f"anchors are (nearly) on one line (spread across it {sv[1]:.3f} m < {MIN_NONCOLLINEARITY_M} m); "
            "the tag's position around that line is unobservable -- spread them around the pad"
        )
    if sv[2] < MIN_NONCOPLANARITY_M and abs(_plane_normal(positions, "above")[2]) < MIN_PLANE_NORMAL_Z:
        return (
            "anchors lie in a steep plane (more than 60 deg from horizontal), so tag_side above/below "
            "does not name a side of it; put them at one height or at clearly different heights"
        )
    return None


def anchor_frame_to_ned(origin_ned_m: ArrayLike, heading_rad: float = 0.0) -> Transform:
    """``T_world_anchorframe`` for an anchor frame with z up whose x axis points along
    ``heading_rad`` (clockwise from north) and whose origin is at ``origin_ned_m`` in world NED.

    heading 0: x north, y west, z up; heading pi/2: x east, y north, z up (ENU), which is the
    vision pad frame: ``anchor_frame_to_ned(o, pi/2 + yaw)`` equals
    ``companion_sitl.camera.pad_pose_ned(*o, yaw_rad=yaw)``.
    """
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    # columns: anchor-frame axes expressed in NED
    x_axis = np.array([c, s, 0.0])
    z_axis = np.array([0.0, 0.0, -1.0])
    y_axis = np.cross(z_axis, x_axis)
    R = np.column_stack([x_axis, y_axis, z_axis])
    return Transform(R, np.asarray(origin_ned_m, dtype=float).reshape(3).copy())


def layout_from_positions(
    positions_m: Sequence[Sequence[float]] | np.ndarray,
    ids: Sequence[str] | None = None,
    frame: str = "pad",
    max_range_m: float = DWM1001_MAX_RANGE_M,
    tag_side: str = "above",
) -> AnchorLayout:
    """Convenience constructor (tests, simulation): ids default to A0, A1, ..."""
    pos = [tuple(float(c) for c in p) for p in np.asarray(positions_m, dtype=float)]
    names = tuple(ids) if ids is not None else tuple(f"A{i}" for i in range(len(pos)))
    return AnchorLayout(names, tuple(pos), frame, names[0], max_range_m, tag_side)  # type: ignore[arg-type]
