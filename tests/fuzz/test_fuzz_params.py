"""Parameter files as bytes, of every kind (``params check`` / ``load_config``).

Rule: a file is loaded as its kind or refused with ConfigError naming the file; never another
exception (not UTF-8, a TOML error, a bad value, a loader's own check)."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from hypothesis import strategies as st

from companion.cli.params import load_params_file
from companion.config import ConfigError, load_config
from companion.param_kinds import KINDS

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
        load_config(p)
        return "loaded"

    for data in vehicle + NASTY:
        harness.check("params toml (load_config)", feed, data, ALLOWED)
    harness.run(
        harness.fuzz_bytes(vehicle + NASTY),
        lambda d: harness.check("params toml (load_config)", feed, d, ALLOWED),
        fuzz_budget,
    )
