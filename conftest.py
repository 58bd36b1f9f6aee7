"""Test tiers (docs/testing.md): every test belongs to one. At the root so that ``--tier`` is known
whatever paths are given (``pytest --tier firmware`` would otherwise read ``firmware`` as the folder).

- ``fast`` (the default): unit and property tests, short links; no whole flight.
- ``flight``: whole missions flown on the embedded simulator or the MAVLink sim vehicle
  (marker ``flight``).
- ``firmware``: the real PX4 SIH and ArduCopter SITL builds (marker ``firmware``; everything under
  tests/real_px4, tests/real_ardupilot and tests/real_firmware), skipped with the reason when a build is absent.
- ``fuzz``: the property-based fuzz tests of every input surface (marker ``fuzz``, tests/fuzz) with
  a large budget; the fast tier runs them too, with a small one (tests/fuzz/conftest.py).

``pytest --tier all`` runs them all (fuzz with the large budget), as CI does.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

TIERS = ("fast", "flight", "firmware", "fuzz", "all")
SITL_GROUP = "real-sitl"
FIRMWARE_DIRS = tuple(Path(__file__).parent / "tests" / d for d in ("real_px4", "real_ardupilot", "real_firmware"))


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


def pytest_itemcollected(item: pytest.Item) -> None:
    """One real SITL at a time (fixed ports): with pytest-xdist (`-n 2 --dist loadgroup`) the
    real-SITL tests are one group, run in order on one worker while the other runs the rest. Marked
    as each test is collected, before xdist's worker names the groups."""
    if any(Path(item.path).is_relative_to(d) for d in FIRMWARE_DIRS):
        item.add_marker(pytest.mark.xdist_group(SITL_GROUP))


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    tier = config.getoption("--tier")
    if os.environ.get("PYTEST_XDIST_WORKER") and config.getvalue("dist") == "no":
        _name_sitl_group(items)
    if tier == "all":
        return
    keep: list[pytest.Item] = []
    drop: list[pytest.Item] = []
    for item in items:
        t = tier_of(item)
        (keep if t == tier or (tier == "fast" and t == "fuzz") else drop).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep


def pytest_runtest_setup(item: pytest.Item) -> None:
    """With pytest-xdist, the worker flying the real SITLs keeps the CPU first: those run on the
    wall clock (a stalled setpoint stream trips the autopilot's failsafe), the rest on simulated time.
    Other tests lower their worker's priority (and their subprocesses'); a firmware test raises it
    back when allowed (as root)."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return
    niceness = os.getpriority(os.PRIO_PROCESS, 0)
    want = 0 if tier_of(item) == "firmware" else 10
    if niceness != want:
        # raising the priority back needs root; without it the CPU is shared evenly
        with contextlib.suppress(PermissionError):
            os.setpriority(os.PRIO_PROCESS, 0, want)


def _name_sitl_group(items: list[pytest.Item]) -> None:
    """xdist's loadgroup schedules by a ``@group`` suffix on each test id, which xdist 3.8 sets in
    ``item._nodeid``; pytest 9.2 keeps the id in ``item._id``, so the suffix is lost and the group
    split over both workers. Set it where pytest reads it (once: a fixed xdist sets it first)."""
    from _pytest.nodeid import coerce_node_id

    suffix = f"@{SITL_GROUP}"
    for item in items:
        if item.get_closest_marker("xdist_group") is not None and not item.nodeid.endswith(suffix):
            item._id = coerce_node_id(item.nodeid + suffix)  # type: ignore[attr-defined]


@pytest.fixture(autouse=True)
def _one_real_sitl_at_a_time(request: pytest.FixtureRequest) -> Iterator[None]:
    """Whatever the scheduling, a real-SITL test waits for the other worker's to end (fixed ports)."""
    if not any(Path(request.node.path).is_relative_to(d) for d in FIRMWARE_DIRS):
        yield
        return
    with open(Path(tempfile.gettempdir()) / "companion-real-sitl.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
