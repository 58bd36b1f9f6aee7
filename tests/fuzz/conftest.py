"""The fuzz tests' budget (from ``--tier``) and the per-surface summary printed at the end of the
session: inputs tried, escapes (goal: 0) and how the inputs ended."""

from __future__ import annotations

import pytest

from .harness import BUDGETS, COUNTS


@pytest.fixture(scope="session")
def fuzz_budget(request: pytest.FixtureRequest) -> int:
    """Examples per fuzz test: small in the fast tier, large in ``--tier fuzz`` / ``--tier all``."""
    tier = request.config.getoption("--tier")
    return BUDGETS["fast" if tier == "fast" else "fuzz"]


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
