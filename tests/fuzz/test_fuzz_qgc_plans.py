"""QGroundControl plan files (``fly --plan``): mutated bytes of plans in QGC's JSON (drops with a
waypoint and release, a payload place with rally points, a fence of polygons and circles, a
complex item) and hostile JSON values (NaN, huge numbers, wrong types), into ``read_plan`` and
``config_from_plan``.

Rule: a new configuration whose pad is one of the plan's items' positions (its alternate another
item's or a rally point's), whose fence holds every polygon and circle the plan has; or
``PlanFileError`` whose reason starts with the file's name; the configuration given is never
changed; never another exception."""

from __future__ import annotations

import itertools
import json
import math

import pytest

from companion.config import shipped_params_path
from companion.delivery.qgc_plan import PlanFileError, config_from_plan, read_plan
from companion.geometry.earth import GeoPoint, ned_to_geo
from companion_sitl.params import load_simulated_config

from . import harness

pytestmark = pytest.mark.fuzz

CONFIG = load_simulated_config(shipped_params_path("sitl_short.toml"))
H = CONFIG.sim.home
HOME = GeoPoint(H.lat_deg, H.lon_deg, H.alt_amsl_m)
BEFORE = CONFIG.model_dump()


def _ll(n: float, e: float) -> list[float]:
    g = ned_to_geo(HOME, n, e, 0.0)
    return [g.lat_deg, g.lon_deg]


def _it(cmd: int, frame: int, params: list) -> dict:
    return {"autoContinue": True, "command": cmd, "doJumpId": 1, "frame": frame, "params": params, "type": "SimpleItem"}


def _plan(items: list, fence: dict | None = None, rally: list | None = None) -> bytes:
    return json.dumps(
        {
            "fileType": "Plan",
            "geoFence": fence or {"circles": [], "polygons": [], "version": 2},
            "groundStation": "QGroundControl",
            "mission": {"items": items, "plannedHomePosition": [H.lat_deg, H.lon_deg, H.alt_amsl_m], "version": 2},
            "rallyPoints": {"points": rally or [], "version": 2},
            "version": 1,
        },
        indent=4,
    ).encode()


TAKEOFF = _it(22, 3, [0, 0, 0, None, *_ll(0, 0), 8])
RELEASE = _it(211, 2, [1, 0, 0, 0, 0, 0, 0])
SEEDS = [
    _plan([TAKEOFF, _it(16, 3, [0, 0, 0, None, *_ll(12, 13), 8]), RELEASE]),
    _plan([TAKEOFF, _it(94, 3, [0, 0, 0, None, *_ll(12, 13), 8])], rally=[[*_ll(-9, 8), 10], [*_ll(30, 30), 10]]),
    _plan(
        [
            _it(21, 0, [0, 0, 0, None, *_ll(12, 13), H.alt_amsl_m + 1]),
            RELEASE,
            _it(94, 6, [0, 0, 0, 0, *_ll(-9, 8), 8]),
        ],
        fence={
            "circles": [{"circle": {"center": _ll(0, 0), "radius": 90}, "inclusion": True, "version": 1}],
            "polygons": [
                {"inclusion": True, "polygon": [_ll(-80, -80), _ll(-80, 80), _ll(80, 80), _ll(80, -80)], "version": 1},
                {"inclusion": False, "polygon": [_ll(40, 40), _ll(40, 50), _ll(50, 50)], "version": 1},
            ],
            "version": 2,
        },
    ),
    _plan([TAKEOFF, {"type": "ComplexItem", "complexItemType": "survey"}, RELEASE]),
    _plan([]),
]
NASTY = [b"", b"{}", b"[]", b'{"fileType": "Plan", "mission": {"version": 2, "items": [NaN]}}', b"\xff\xfe{"]


def _positions(path) -> set[tuple[float, float]]:
    """Every (lat, lon) the plan file names: items' params 5-6 and rally points."""
    data = json.loads(path.read_text())
    out = set()
    for it in data["mission"]["items"]:
        out.add((float(it["params"][4] or 0.0), float(it["params"][5] or 0.0)))
    for p in data.get("rallyPoints", {}).get("points", []):
        out.add((float(p[0]), float(p[1])))
    return out


def _near(lat: float, lon: float, positions: set[tuple[float, float]]) -> bool:
    return any(math.isclose(lat, a, abs_tol=1e-9) and math.isclose(lon, b, abs_tol=1e-9) for a, b in positions)


def test_plan_files_into_a_delivery(tmp_path, fuzz_budget) -> None:
    n = itertools.count()

    def feed(data: bytes) -> str:
        p = tmp_path / f"p{next(n)}.plan"
        p.write_bytes(data)
        try:
            flown, said = config_from_plan(CONFIG, read_plan(p))
        except PlanFileError as err:
            assert err.reason.startswith(str(p)), err.reason  # the file is named
            raise
        finally:
            assert CONFIG.model_dump() == BEFORE  # the configuration given is never changed
        where = _positions(p)
        m = flown.mission
        assert _near(m.pad.lat_deg, m.pad.lon_deg, where), (m.pad, where)
        if m.alternate_pad is not None and m.alternate_pad.lat_deg is not None:
            assert _near(m.alternate_pad.lat_deg, m.alternate_pad.lon_deg, where)
        shapes = json.loads(p.read_text()).get("geoFence") or {}
        n_shapes = len(shapes.get("polygons", [])) + len(shapes.get("circles", []))
        if n_shapes:
            assert flown.fence.enabled and len(flown.fence.inclusion) + len(flown.fence.exclusion) == n_shapes
        return "flown" if said else "?"

    for data in SEEDS + NASTY:
        harness.check("qgc plan (config_from_plan)", feed, data, (PlanFileError,))
    harness.run(
        harness.fuzz_bytes(SEEDS + NASTY),
        lambda d: harness.check("qgc plan (config_from_plan)", feed, d, (PlanFileError,)),
        fuzz_budget,
    )
