"""Test tiers (docs/testing.md): every test belongs to one. At the root so that ``--tier`` is known
whatever paths are given (``pytest --tier firmware`` would otherwise read ``firmware`` as the folder).

- ``fast`` (the default): unit and property tests, short links; no whole flight.
- ``flight``: whole missions flown on the embedded simulator or the MAVLink sim vehicle
  (marker ``flight``).
- ``firmware``: the real PX4 SIH and ArduCopter SITL builds (marker ``firmware``; everything under
  tests/real_px4 and tests/real_ardupilot), skipped with the reason when a build is absent.
- ``fuzz``: the property-based fuzz tests of every input surface (marker ``fuzz``, tests/fuzz) with
  a large budget; the fast tier runs them too, with a small one (tests/fuzz/conftest.py).

``pytest --tier all`` runs them all (fuzz with the large budget), as CI does.
"""

from __future__ import annotations

from pathlib import Path

import pytest

TIERS = ("fast", "flight", "firmware", "fuzz", "all")
FIRMWARE_DIRS = tuple(Path(__file__).parent / "tests" / d for d in ("real_px4", "real_ardupilot"))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--tier",
        choices=TIERS,
        default="fast",
        help="which tests to run: fast (default), flight, firmware, fuzz or all",
    )


def tier_of(item: pytest.Item) -> str:
    """The tier a collected test belongs to (firmware wins over flight, flight over fuzz)."""
    if item.get_closest_marker("firmware") or any(Path(item.path).is_relative_to(d) for d in FIRMWARE_DIRS):
        return "firmware"
    if item.get_closest_marker("flight"):
        return "flight"
    if item.get_closest_marker("fuzz"):
        return "fuzz"
    return "fast"


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    tier = config.getoption("--tier")
    if tier == "all":
        return
    keep, drop = [], []
    for item in items:
        t = tier_of(item)
        (keep if t == tier or (tier == "fast" and t == "fuzz") else drop).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep
