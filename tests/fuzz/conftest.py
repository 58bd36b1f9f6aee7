"""The fuzz tests' budget (from ``--tier``) and the per-surface summary printed at the end of the
session: inputs tried, escapes (goal: 0) and how the inputs ended."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.config import shipped_params_path
from companion_sitl.params import load_simulated_config

from .harness import BUDGETS, COUNTS, RUN_FOLDER_BUDGETS, SIM_START_BUDGETS, SIM_START_S


@pytest.fixture(scope="session")
def fuzz_budget(fuzz_tier: str) -> int:
    """Examples per fuzz test: small in the fast tier, large in ``--tier fuzz`` / ``--tier all``."""
    return BUDGETS[fuzz_tier]


@pytest.fixture(scope="session")
def fuzz_tier(request: pytest.FixtureRequest) -> str:
    """The budget tier: fast, or fuzz (``--tier fuzz`` and ``--tier all``)."""
    return "fast" if request.config.getoption("--tier") == "fast" else "fuzz"


@pytest.fixture(scope="session")
def run_folder_budget(fuzz_tier: str) -> int:
    """Generated run folders per test (each replay or report takes one to three seconds)."""
    return RUN_FOLDER_BUDGETS[fuzz_tier]


@pytest.fixture(scope="session")
def sim_start_budget(fuzz_tier: str) -> tuple[int, float]:
    """(generated files, simulated seconds each accepted one flies) of the params-to-simulator property."""
    return SIM_START_BUDGETS[fuzz_tier], SIM_START_S[fuzz_tier]


@pytest.fixture(scope="session")
def fuzz_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One real run folder (the short delivery with fusion, about 2 s), built once: the seed the
    run-folder tests mutate copies of."""
    from companion_lab.demo import run_demo

    run = tmp_path_factory.mktemp("fuzz-demo") / "run"
    over = {"sim": {"seed": 3, "gps_bias_m": [1.0, -0.5, 0.0], "pad_offset_m": [0.3, -0.2]}}
    r = run_demo(load_simulated_config(shipped_params_path("sitl_short.toml"), overrides=over), run_dir=run)
    assert r.delivered and r.returned, r.failure
    return run


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if not COUNTS:
        return
    tr = terminalreporter
    tr.section("fuzz: inputs tried and escaped per surface")
    width = max(len(s) for s in COUNTS)
    tr.write_line(f"{'surface':<{width}}  {'tried':>7}  {'escaped':>7}  outcomes")
    for surface in sorted(COUNTS):
        c = COUNTS[surface]
        top = ", ".join(f"{k} {n}" for k, n in c.outcomes.most_common(6))
        tr.write_line(f"{surface:<{width}}  {c.tried:>7}  {c.escaped:>7}  {top}")
        if c.first_escape:
            tr.write_line(f"{'':<{width}}  first escape: {c.first_escape}")
    tried = sum(c.tried for c in COUNTS.values())
    escaped = sum(c.escaped for c in COUNTS.values())
    tr.write_line(f"{'total':<{width}}  {tried:>7}  {escaped:>7}")
