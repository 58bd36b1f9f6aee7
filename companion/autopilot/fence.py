"""The autopilot's own fence: the ``[fence]`` polygons as MAVLink fence items (MISSION_ITEM_INT,
mission_type MAV_MISSION_TYPE_FENCE, MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION / _EXCLUSION),
and the comparison of what was read back with what was sent (docs/go-no-go.md).

A vertex is kept as MAVLink carries it, integer 1e-7 degrees, so a read-back compares exactly
(within one unit: PX4 keeps the vertices as doubles and MAVSDK rounds them on the way)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from companion.config import FenceConfig

MAV_MISSION_TYPE_FENCE = 1
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002
MAV_FRAME_GLOBAL = 0
VERTEX_INCLUSION, VERTEX_EXCLUSION = (
    MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
    MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
)
E7_TOLERANCE = 1  # 1e-7 deg, 1.1 cm


@dataclass(frozen=True, slots=True)
class FencePolygon:
    inclusion: bool
    vertices_e7: tuple[tuple[int, int], ...]  # (lat, lon) in 1e-7 degrees


@dataclass(frozen=True, slots=True)
class AutopilotFence:
    polygons: tuple[FencePolygon, ...]

    def describe(self) -> str:
        inc = sum(p.inclusion for p in self.polygons)
        verts = sum(len(p.vertices_e7) for p in self.polygons)
        return f"{inc} inclusion and {len(self.polygons) - inc} exclusion polygons, {verts} vertices"


@dataclass(frozen=True, slots=True)
class FenceItem:
    """One MISSION_ITEM_INT of the fence: a polygon vertex."""

    seq: int
    command: int
    vertex_count: int  # param1
    group: int  # param2: inclusion group (ArduPilot; 0 = PX4's)
    lat_e7: int
    lon_e7: int


def _e7(deg: float) -> int:
    return round(deg * 1e7)


def fence_from_config(cfg: FenceConfig) -> AutopilotFence:
    polys = [FencePolygon(True, tuple((_e7(a), _e7(o)) for a, o in p.vertices_deg)) for p in cfg.inclusion]
    polys += [FencePolygon(False, tuple((_e7(a), _e7(o)) for a, o in p.vertices_deg)) for p in cfg.exclusion]
    return AutopilotFence(tuple(polys))


def fence_items(fence: AutopilotFence) -> list[FenceItem]:
    """The mission items of the fence, in order (each polygon's vertices together)."""
    items: list[FenceItem] = []
    for group, poly in enumerate(fence.polygons):
        cmd = (
            MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION if poly.inclusion else MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
        )
        for lat, lon in poly.vertices_e7:
            items.append(FenceItem(len(items), cmd, len(poly.vertices_e7), group if poly.inclusion else 0, lat, lon))
    return items


class FenceItemsError(ValueError):
    """Fence items read back from an autopilot do not make polygons."""


def fence_from_items(items: Sequence[FenceItem]) -> AutopilotFence:
    """Polygons from fence items read back; items of other kinds (circles, the return point)
    are reported as an error: the companion sent none."""
    polys: list[FencePolygon] = []
    i = 0
    while i < len(items):
        it = items[i]
        if it.command not in (MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
            raise FenceItemsError(f"item {i}: command {it.command} is not a polygon vertex")
        n = it.vertex_count
        group = items[i : i + n]
        if n < 3 or len(group) < n or any(g.command != it.command or g.vertex_count != n for g in group):
            raise FenceItemsError(f"item {i}: a polygon of {n} vertices is not followed by its {n} vertices")
        polys.append(
            FencePolygon(
                it.command == MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, tuple((g.lat_e7, g.lon_e7) for g in group)
            )
        )
        i += n
    return AutopilotFence(tuple(polys))


def fence_mismatch(sent: AutopilotFence, got: AutopilotFence) -> str | None:
    """How the fence read back differs from the one sent (None: the same polygons, in order,
    each vertex within one 1e-7 degree)."""
    if len(sent.polygons) != len(got.polygons):
        return f"sent {sent.describe()}, read back {got.describe()}"
    for i, (a, b) in enumerate(zip(sent.polygons, got.polygons, strict=True)):
        kind = "inclusion" if a.inclusion else "exclusion"
        if a.inclusion != b.inclusion:
            return f"polygon {i}: sent as {kind}, read back as {'inclusion' if b.inclusion else 'exclusion'}"
        if len(a.vertices_e7) != len(b.vertices_e7):
            return f"polygon {i} ({kind}): sent {len(a.vertices_e7)} vertices, read back {len(b.vertices_e7)}"
        for j, (va, vb) in enumerate(zip(a.vertices_e7, b.vertices_e7, strict=True)):
            if abs(va[0] - vb[0]) > E7_TOLERANCE or abs(va[1] - vb[1]) > E7_TOLERANCE:
                return (
                    f"polygon {i} ({kind}) vertex {j}: sent ({va[0] / 1e7:.7f}, {va[1] / 1e7:.7f}), "
                    f"read back ({vb[0] / 1e7:.7f}, {vb[1] / 1e7:.7f})"
                )
    return None
