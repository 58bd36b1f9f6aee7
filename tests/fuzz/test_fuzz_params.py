"""Parameter files of every kind (``params check`` / ``load_config``), as bytes and as values.

Rules: a file is loaded as its kind or refused with ConfigError naming the file, and each of its
problems naming the key (or the file's own fault: not TOML, not UTF-8); never another exception
(not UTF-8, a TOML error, a bad value, a loader's own check). And what ``params check`` accepts
the embedded simulator starts with: a shipped vehicle file with one number set at or past its
limits, NaN, infinite or huge is either refused naming that key (a non-finite one as "not
finite", never compared with a limit) or flies its first seconds without an exception."""

from __future__ import annotations

import copy
import itertools
import json
import math
import re
import typing
from pathlib import Path
from typing import Any

import pytest
from hypothesis import strategies as st
from pydantic import BaseModel

from companion.cli.params import load_params_file
from companion.config import ConfigError, read_toml
from companion.param_kinds import KINDS, detect_kind
from companion_sitl.params import SimulatedConfig, load_simulated_config

from . import harness

pytestmark = pytest.mark.fuzz

PARAMS = Path(__file__).resolve().parents[2] / "params"
#: the shipped files of every kind are the valid seeds
SEEDS = [p.read_bytes() for p in sorted(PARAMS.glob("*.toml"))]
#: known-nasty files: not UTF-8, a BOM, NUL, a huge integer, deep nesting, a key redefined,
#: values of the wrong type, non-finite floats, an empty file
NASTY = [
    b"",
    b"\xff\xfe[mission]\n",
    b"\xef\xbb\xbf[mission]\ncruise_alt_m = 40\n",
    b"[mission]\ncruise_alt_m = 4\x000\n",
    b"[mission]\ncruise_alt_m = " + b"9" * 5000 + b"\n",
    b"[mission]\ncruise_alt_m = nan\n[limits]\nmax_speed_m_s = inf\n",
    b"a = " + b"[" * 2000 + b"]" * 2000 + b"\n",
    b"[mission]\n[mission]\n",
    b"[mission]\ncruise_alt_m = '40'\npad_offset_m = [1, 'x']\n",
    b"[sim]\nseed = -1\n[runtime]\nrate_hz = 1e400\n",
    b"[[anchors]]\nid = 1\nposition_m = [1e308, 1e308, 1e308]\n",
    b"mode = 'peer'\nendpoints = [1, 2]\n",
    b"[camera]\nwidth_px = 0\nheight_px = -1\n",
]
ALLOWED = (ConfigError,)
#: a problem that names its key: "KEY = VALUE: rule", "TABLE: a rule between its keys", "KEY (VALUE) must ..."
_KEYED = re.compile(r"^[\w-][\w.\[\]-]*( = |: | \()")  # TOML bare keys may start with a digit
#: the file's own faults, before any key: not TOML, not UTF-8, unreadable
_FILE_LEVEL = ("not valid TOML", "not UTF-8", "cannot read", "file not found")
_TABLE_NAMED = re.compile(r"\[\w+\] table|key '\w+'")


def _names_a_key(problem: str) -> bool:
    return bool(_KEYED.match(problem)) or problem.startswith(_FILE_LEVEL) or bool(_TABLE_NAMED.search(problem))


def test_params_files_of_every_kind(tmp_path, fuzz_budget) -> None:
    n = itertools.count()

    def feed(item: tuple[bytes, str | None]) -> str:
        data, kind = item
        p = tmp_path / f"p{next(n)}.toml"
        p.write_bytes(data)
        try:
            k, _model = load_params_file(p, kind)
        except ConfigError as err:
            assert str(p) in str(err), f"the error does not name the file: {err}"
            unnamed = [q for q in err.problems if not _names_a_key(q)]
            assert not unnamed, f"problems that name no key: {unnamed}"
            raise
        return f"loaded ({k})"

    kinds = st.sampled_from([None, *KINDS])
    for data in SEEDS + NASTY:
        harness.check("params toml (params check)", feed, (data, None), ALLOWED)
    harness.run(
        st.tuples(harness.fuzz_bytes(SEEDS + NASTY), kinds),
        lambda item: harness.check("params toml (params check)", feed, item, ALLOWED),
        fuzz_budget,
    )


def test_load_config_bytes(tmp_path, fuzz_budget) -> None:
    n = itertools.count()
    vehicle = [s for s in SEEDS if b"[mission]" in s or b"[sim]" in s] or SEEDS

    def feed(data: bytes) -> str:
        p = tmp_path / f"c{next(n)}.toml"
        p.write_bytes(data)
        load_simulated_config(p)
        return "loaded"

    for data in vehicle + NASTY:
        harness.check("params toml (load_config)", feed, data, ALLOWED)
    harness.run(
        harness.fuzz_bytes(vehicle + NASTY),
        lambda d: harness.check("params toml (load_config)", feed, d, ALLOWED),
        fuzz_budget,
    )


# ------------------------------------------------------- what params check accepts, the simulator starts
#: the shipped vehicle files, the bases the values are set in
VEHICLES = {p.name: read_toml(p) for p in sorted(PARAMS.glob("*.toml")) if detect_kind(read_toml(p)) == "vehicle"}
_HUGE = (math.nan, math.inf, -math.inf, 1e300, -1e300, 1e9, -1e9, 0.0, -1.0)


def _sub_model(annotation: Any) -> type[BaseModel] | None:
    """The table type of a field (``PadConfig``, ``PadConfig | None``), or None for a value."""
    for a in (annotation, *typing.get_args(annotation)):
        if isinstance(a, type) and issubclass(a, BaseModel):
            return a
    return None


def _numbers(schema: type[BaseModel], prefix: str = "") -> list[tuple[str, int | None, Any]]:
    """(dotted key, element index or None, field) of every number the vehicle file declares: a
    float or int key, or one element of a fixed-length tuple of floats."""
    out: list[tuple[str, int | None, Any]] = []
    for name, f in schema.model_fields.items():
        key, ann = prefix + name, f.annotation
        sub = _sub_model(ann)
        if sub is not None:
            out += _numbers(sub, key + ".")
        elif ann in (float, int, float | None, int | None):
            out.append((key, None, f))
        elif typing.get_origin(ann) is tuple and all(a is float for a in typing.get_args(ann)):
            out += [(key, i, f) for i in range(len(typing.get_args(ann)))]
    return out


NUMBERS = _numbers(SimulatedConfig)


def _edge_values(f: Any) -> list[float | int]:
    """Values at and just past the field's limits, around them, and NaN, infinite, huge."""
    is_int = f.annotation in (int, int | None)
    limits = [getattr(m, a) for m in f.metadata for a in ("ge", "gt", "le", "lt") if getattr(m, a, None) is not None]
    if is_int:
        return sorted({v + d for v in limits for d in (-1, 0, 1)} | {0, -1, 2**63 - 1, -(2**63)})
    near = [x for v in limits for x in (v, math.nextafter(v, math.inf), math.nextafter(v, -math.inf), v + 1, v * 10)]
    return [float(x) for x in near] + list(_HUGE)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # JSON's escapes are TOML basic-string escapes
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML for {v!r}")


def _is_tables(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def toml_text(data: dict[str, Any], prefix: str = "") -> str:
    """``data`` (as tomllib reads it) written back as TOML: values, then tables, then arrays of tables."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, dict) and not _is_tables(v)]
    for k, v in data.items():
        if isinstance(v, dict):
            lines += [f"[{prefix}{k}]", toml_text(v, f"{prefix}{k}.")]
        elif _is_tables(v):
            for item in v:
                lines += [f"[[{prefix}{k}]]", toml_text(item, f"{prefix}{k}.")]
    return "\n".join(lines) + "\n"


def _with_value(base: dict[str, Any], key: str, index: int | None, value: Any) -> dict[str, Any]:
    """A copy of ``base`` with ``key`` (element ``index`` of it) set to ``value``; the other
    elements of a tuple keep the file's values, or the defaults."""
    data = copy.deepcopy(base)
    *tables, leaf = key.split(".")
    node = data
    for t in tables:
        node = node.setdefault(t, {})
    if index is not None:
        default = SimulatedConfig.model_validate(base)
        for name in key.split("."):
            default = getattr(default, name)
        items = list(node.get(leaf, default))
        items[index] = value
        value = items
    node[leaf] = value
    return data


def test_the_writer_gives_back_every_shipped_vehicle_file(tmp_path) -> None:
    for name, data in VEHICLES.items():
        p = tmp_path / name
        p.write_text(toml_text(data))
        assert read_toml(p) == data, name
    assert len(NUMBERS) > 170  # every float, int and float-tuple element of the vehicle file


def _check_or_fly(tmp_path: Path, sim_s: float) -> Any:
    from companion_lab.demo import fly
    from companion_sitl.clock import run_virtual

    n = itertools.count()

    def feed(item: tuple[str, tuple[str, int | None, Any], float | int]) -> str:
        base, (key, index, _f), value = item
        p = tmp_path / f"v{next(n)}.toml"
        p.write_text(toml_text(_with_value(VEHICLES[base], key, index, value)))
        shown = f"{key}[{index}]" if index is not None else key
        try:
            kind, cfg = load_params_file(p)
        except ConfigError as err:
            text = "; ".join(err.problems)
            assert str(p) in str(err), err
            parent, _, leaf = key.rpartition(".")
            assert any(n in text for n in (key, leaf, parent)), f"{shown} = {value!r} refused naming no key: {text}"
            if isinstance(value, float) and not math.isfinite(value):
                assert f"{shown} = {value!r}: not finite" in text, text
                assert "should be" not in text, text  # a NaN is never compared with a limit
            return "refused, naming the key"
        assert kind == "vehicle" and isinstance(cfg, SimulatedConfig)
        result = run_virtual(fly(cfg, run_dir=p.with_suffix(""), timeout_s=sim_s))
        assert math.isfinite(result.sim_time_s) and result.sim_time_s > 0.0, result
        return "accepted, the simulator started"

    return feed


def test_what_params_check_accepts_the_simulator_starts(tmp_path, sim_start_budget) -> None:
    examples, sim_s = sim_start_budget
    feed = _check_or_fly(tmp_path, sim_s)
    surface = "params value -> check or simulator"
    by_key = {(k, i): f for k, i, f in NUMBERS}
    pad = ("mission.pad.north_m", None)
    # the reported cases, every tier: non-finite and huge pad offsets and heights, one at the limit
    for key, value in (
        (pad, math.nan),
        (pad, math.inf),
        (pad, 1e7),
        (pad, 1e9),
        (("mission.pad.alt_amsl_m", None), math.nan),
        (("mission.height_m", None), math.nan),
        (("sim.gps_bias_m", 1), math.inf),
        (pad, 3000.0),
    ):
        harness.check(surface, feed, ("sitl_short.toml", (*key, by_key[key]), value), ALLOWED)
    values = st.tuples(st.sampled_from(sorted(VEHICLES)), st.sampled_from(NUMBERS)).flatmap(
        lambda bk: st.tuples(st.just(bk[0]), st.just(bk[1]), st.sampled_from(_edge_values(bk[1][2])))
    )
    harness.run(values, lambda item: harness.check(surface, feed, item, ALLOWED), examples)
