"""A short seeded demo flight (fusion: GPS + camera + UWB) shared by the flight-log tests."""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from companion.config import shipped_params_path
from companion.flightlog.logproc import LogProcess
from companion_sitl.params import load_simulated_config


def short_config(**sim):
    over = {"sim": {"seed": 3, **sim}}
    return load_simulated_config(shipped_params_path("sitl_short.toml"), overrides=over)


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory) -> Path:
    """Run folder of the short delivery (35 s simulated, about 2 s wall) with a GPS bias and a
    displaced pad, so the fusion has something to estimate. Tests copy it before changing it."""
    from companion_lab.demo import run_demo

    run = tmp_path_factory.mktemp("demo") / "run"
    r = run_demo(short_config(gps_bias_m=[1.0, -0.5, 0.0], pad_offset_m=[0.3, -0.2]), run_dir=run)
    assert r.delivered and r.returned, r.failure
    return run


@pytest.fixture
def run_copy(demo_run, tmp_path) -> Path:
    dst = tmp_path / "run"
    shutil.copytree(demo_run, dst)
    return dst


def wait_gone(pid: int, timeout_s: float = 60.0) -> None:
    """Until the process has exited (a zombie counts: it has closed its files)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (FileNotFoundError, ProcessLookupError):
            return
        if state in ("Z", "X"):
            return
        time.sleep(0.05)
    raise AssertionError(f"the logging process {pid} did not exit")


@pytest.fixture
def own_process() -> Iterator[None]:
    """A logging process of the test's own (it may kill it), the suite's one restored after."""
    saved = LogProcess._current, LogProcess._failed_pid
    LogProcess._current = None
    LogProcess._failed_pid = None
    try:
        yield
    finally:
        cur = LogProcess._current
        if cur is not None and cur is not saved[0]:
            cur.shutdown()
        LogProcess._current, LogProcess._failed_pid = saved
