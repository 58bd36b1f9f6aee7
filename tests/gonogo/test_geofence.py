"""The geofence: polygon arithmetic, the [fence] table's validation, the planned legs against the
polygons (hand-computed places), and the fence items sent to / read back from an autopilot."""

from __future__ import annotations

import math

import pytest

from companion.autopilot.fence import (
    MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
    MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
    AutopilotFence,
    FenceItem,
    FenceItemsError,
    FencePolygon,
    fence_from_config,
    fence_from_items,
    fence_items,
    fence_mismatch,
)
from companion.config import ConfigError, FenceConfig, LimitsConfig
from companion.geometry.earth import GeoPoint, ned_to_geo
from companion.geometry.polygon import (
    point_in_polygon,
    polygon_problem,
    segment_crossing_t,
    segments_intersect,
)
from companion.guidance.geofence import check_leg, fence_in_ned, section_at
from companion_sitl.params import simulated_config_from_dict

HOME = GeoPoint(-19.869, -43.9638, 850.0)
SQUARE = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]


def geo(n: float, e: float) -> list[float]:
    g = ned_to_geo(HOME, n, e, 0.0)
    return [g.lat_deg, g.lon_deg]


def square_deg(n0: float, e0: float, n1: float, e1: float) -> list[list[float]]:
    return [geo(n0, e0), geo(n1, e0), geo(n1, e1), geo(n0, e1)]


# ---------------------------------------------------------------- polygon arithmetic
def test_point_in_polygon_and_on_edge() -> None:
    assert point_in_polygon((5.0, 5.0), SQUARE)
    assert not point_in_polygon((11.0, 5.0), SQUARE)
    assert point_in_polygon((10.0, 5.0), SQUARE)  # on an edge counts as inside
    concave = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (5.0, 2.0), (0.0, 10.0)]
    assert not point_in_polygon((5.0, 6.0), concave)  # in the notch
    assert point_in_polygon((2.0, 3.0), concave)


def test_segment_crossing_place() -> None:
    # from (-5, 5) to (15, 5): enters the square's edge x = 0 a quarter of the way along
    assert segment_crossing_t((-5.0, 5.0), (15.0, 5.0), (0.0, 0.0), (0.0, 10.0)) == pytest.approx(0.25)
    assert segment_crossing_t((-5.0, 5.0), (-1.0, 5.0), (0.0, 0.0), (0.0, 10.0)) is None
    assert segments_intersect((0.0, 0.0), (1.0, 1.0), (1.0, 1.0), (2.0, 0.0))  # touching


def test_polygon_problems_are_named() -> None:
    assert polygon_problem(SQUARE) is None
    assert "at least 3" in (polygon_problem(SQUARE[:2]) or "")
    bowtie = [(0.0, 0.0), (10.0, 10.0), (10.0, 0.0), (0.0, 10.0)]
    assert "crosses" in (polygon_problem(bowtie) or "")
    assert "same point" in (polygon_problem([(0.0, 0.0), (1.0, 0.0), (0.0, 0.0), (0.0, 1.0)]) or "")
    assert "no area" in (polygon_problem([(0.0, 0.0), (1.0, 0.0), (2.0, 0.0)]) or "")


# ---------------------------------------------------------------- [fence] validation
def _cfg(fence: dict[str, object], **extra: object) -> object:
    """The simulator's config: the fence holds the simulated home too."""
    return simulated_config_from_dict({"fence": fence, **extra}, "test.toml")


def test_fence_table_validation_names_key_and_rule() -> None:
    with pytest.raises(ConfigError, match=r"fence: fence.enabled needs at least one \[\[fence.inclusion\]\]"):
        _cfg({"enabled": True})
    with pytest.raises(ConfigError, match=r"fence.inclusion\[0\].vertices_deg = .*crosses"):
        _cfg({"inclusion": [{"vertices_deg": [[0, 0], [1, 1], [1, 0], [0, 1]]}]})
    with pytest.raises(ConfigError, match=r"vertex 1 latitude 95"):
        _cfg({"inclusion": [{"vertices_deg": [[0, 0], [95, 0], [0, 1]]}]})
    with pytest.raises(ConfigError, match=r"vertex 2 longitude 181"):
        _cfg({"inclusion": [{"vertices_deg": [[0, 0], [1, 0], [0, 181]]}]})
    with pytest.raises(ConfigError, match="at least 3"):
        _cfg({"inclusion": [{"vertices_deg": [[0, 0], [1, 0], [0, 0]]}]})  # closed by repeating the first
    # the simulated home must lie inside the fence
    with pytest.raises(ConfigError, match=r"sim.home .* is outside inclusion polygon 0"):
        _cfg({"enabled": True, "inclusion": [{"vertices_deg": square_deg(10, 10, 200, 200)}]})
    with pytest.raises(ConfigError, match=r"sim.home .* is inside exclusion polygon 0"):
        _cfg(
            {
                "enabled": True,
                "inclusion": [{"vertices_deg": square_deg(-300, -300, 300, 300)}],
                "exclusion": [{"vertices_deg": square_deg(-5, -5, 5, 5)}],
            }
        )


def test_fence_table_accepts_a_closed_polygon() -> None:
    ring = [*square_deg(-300, -300, 300, 300), square_deg(-300, -300, 300, 300)[0]]
    cfg = _cfg({"enabled": True, "inclusion": [{"vertices_deg": ring}]})
    assert len(cfg.fence.inclusion[0].vertices_deg) == 4  # type: ignore[attr-defined]


# ---------------------------------------------------------------- the legs against the fence
LIMITS = LimitsConfig()


def _fence(inclusion: list[list[list[float]]], exclusion: list[list[list[float]]] = (), **kw: object) -> object:  # type: ignore[assignment]
    cfg = FenceConfig(
        enabled=True,
        inclusion=[{"vertices_deg": v} for v in inclusion],  # type: ignore[list-item]
        exclusion=[{"vertices_deg": v} for v in exclusion],  # type: ignore[list-item]
        **kw,  # type: ignore[arg-type]
    )
    return fence_in_ned(cfg, HOME)


def test_sections_along_a_leg() -> None:
    d, r = 100.0, 6.0
    assert section_at(0.0, d, r, "outbound") == "S1 climb from home"
    assert section_at(3.0, d, r, "outbound") == "S2 arc"
    assert section_at(50.0, d, r, "outbound") == "S3 cruise"
    assert section_at(97.0, d, r, "outbound") == "S4 arc"
    assert section_at(100.0, d, r, "outbound") == "S5 descent to the pad"
    assert section_at(3.0, d, r, "return") == "S4 arc"
    assert section_at(100.0, d, r, "return") == "S1 descent home"


def test_leg_inside_passes() -> None:
    fence = _fence([square_deg(-20, -20, 120, 20)])
    assert check_leg(fence, LIMITS, HOME, (0, 0, 0), (100, 0, 0), -45.0, 6.0) is None  # type: ignore[arg-type]


def test_leg_leaving_the_inclusion_is_placed_in_the_cruise() -> None:
    # the inclusion ends at north 60 m; margin 5 m -> the first point too close is 55 m along
    fence = _fence([square_deg(-20, -20, 60, 20)])
    v = check_leg(fence, LIMITS, HOME, (0, 0, 0), (100, 0, 0), -45.0, 6.0)  # type: ignore[arg-type]
    assert v is not None
    assert v.section == "S3 cruise" and v.leg == "outbound"
    assert v.along_m == pytest.approx(55.0, abs=0.01)
    assert v.north_m == pytest.approx(55.0, abs=0.01) and v.east_m == pytest.approx(0.0, abs=1e-9)
    assert "inclusion polygon 0" in v.reason and "margin" in v.reason
    g = ned_to_geo(HOME, 55.0, 0.0, 0.0)
    assert v.lat_deg == pytest.approx(g.lat_deg, abs=1e-9)
    # without a margin: it leaves at the edge itself, 60.5 m (the first sample past 60 m)
    fence0 = _fence([square_deg(-20, -20, 60, 20)], margin_m=0.0)
    v0 = check_leg(fence0, LIMITS, HOME, (0, 0, 0), (100, 0, 0), -45.0, 6.0)  # type: ignore[arg-type]
    assert v0 is not None and v0.along_m == pytest.approx(60.5, abs=0.01) and "outside inclusion" in v0.reason


def test_exclusion_across_the_leg_and_a_thin_one() -> None:
    fence = _fence([square_deg(-20, -20, 120, 20)], [square_deg(40, -10, 50, 10)], margin_m=2.0)
    v = check_leg(fence, LIMITS, HOME, (0, 0, 0), (100, 0, 0), -45.0, 6.0)  # type: ignore[arg-type]
    # 38.0 m along is exactly 2 m from the edge (allowed); the next sample, 38.5 m, is 1.5 m from it
    assert v is not None and "exclusion polygon 0" in v.reason and v.along_m == pytest.approx(38.5, abs=0.01)
    # a wall 1 cm thick, between two samples (0.5 m apart), no margin: found by the exact crossing
    fence2 = _fence([square_deg(-20, -20, 120, 20)], [square_deg(40.2, -10, 40.21, 10)], margin_m=0.0)
    v2 = check_leg(fence2, LIMITS, HOME, (0, 0, 0), (100, 0, 0), -45.0, 6.0)  # type: ignore[arg-type]
    assert v2 is not None and "crosses the edge of exclusion polygon 0" in v2.reason
    assert v2.along_m == pytest.approx(40.2, abs=0.01)


def test_return_leg_is_named_and_ceiling() -> None:
    fence = _fence([square_deg(-20, -20, 120, 20)], max_alt_rel_m=40.0)
    v = check_leg(fence, LIMITS, HOME, (100, 0, 0), (0, 0, 0), -45.0, 6.0, leg="return")  # type: ignore[arg-type]
    assert v is not None and v.leg == "return" and "ceiling" in v.reason and "45.0 m above home" in v.reason
    assert v.section == "S3 cruise" and v.along_m == pytest.approx(6.0)  # the top starts after the arc


def test_companion_clamp_is_checked_without_a_fence() -> None:
    limits = LimitsConfig(geofence_radius_m=80.0)
    v = check_leg(None, limits, HOME, (0, 0, 0), (100, 0, 0), -45.0, 6.0)
    assert v is not None and "geofence_radius_m = 80" in v.reason and v.section == "S5 descent to the pad"
    v = check_leg(None, LimitsConfig(geofence_max_alt_m=40.0), HOME, (0, 0, 0), (100, 0, 0), -45.0, 6.0)
    assert v is not None and "geofence_max_alt_m = 40" in v.reason
    assert check_leg(None, LIMITS, HOME, (0, 0, 0), (100, 0, 0), -45.0, 6.0) is None


# ---------------------------------------------------------------- fence items
def test_fence_items_round_trip_and_mismatch() -> None:
    cfg = FenceConfig(
        enabled=True,
        inclusion=[{"vertices_deg": square_deg(-50, -50, 150, 150)}],  # type: ignore[list-item]
        exclusion=[{"vertices_deg": [geo(40, 40), geo(50, 40), geo(45, 50)]}],  # type: ignore[list-item]
    )
    fence = fence_from_config(cfg)
    items = fence_items(fence)
    assert [it.command for it in items] == [MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION] * 4 + [
        MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
    ] * 3
    assert [it.vertex_count for it in items] == [4] * 4 + [3] * 3
    assert items[0].lat_e7 == round(cfg.inclusion[0].vertices_deg[0][0] * 1e7)
    assert fence_from_items(items) == fence
    assert fence_mismatch(fence, fence) is None
    moved = AutopilotFence(
        (FencePolygon(True, ((fence.polygons[0].vertices_e7[0][0] + 2, fence.polygons[0].vertices_e7[0][1]),
                             *fence.polygons[0].vertices_e7[1:])), fence.polygons[1])
    )  # fmt: skip
    assert "polygon 0 (inclusion) vertex 0" in (fence_mismatch(fence, moved) or "")
    assert "read back 1 inclusion and 0 exclusion" in (fence_mismatch(fence, AutopilotFence(fence.polygons[:1])) or "")
    with pytest.raises(FenceItemsError, match="not followed by its 4 vertices"):
        fence_from_items(items[:3])
    with pytest.raises(FenceItemsError, match="not a polygon vertex"):
        fence_from_items([FenceItem(0, 5003, 0, 0, 0, 0)])
    assert math.isfinite(items[-1].lon_e7)
