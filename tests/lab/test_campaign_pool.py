"""The landing campaign's worker processes: a failed landing, a worker that dies and Ctrl-C each
end the campaign naming the landing, and leave no worker behind."""

import multiprocessing
import os
import signal
import time

import pytest

from companion_lab import campaign_pool
from companion_lab.campaign_landing import CampaignLandingError
from companion_lab.landing_campaign import run_landing_campaign

pytestmark = pytest.mark.flight


def _no_workers_left(timeout_s: float = 10.0) -> bool:
    end = time.monotonic() + timeout_s
    while multiprocessing.active_children() and time.monotonic() < end:
        time.sleep(0.1)
    return not multiprocessing.active_children()


def _on_first_start(monkeypatch, act):
    """Call ``act(pid)`` once, as soon as a worker reports the landing it starts."""
    drain = campaign_pool._Workers.drain
    acted = []

    def drain_then_act(self):
        drain(self)
        if self.flying and not acted:
            acted.append(True)
            act(next(iter(self.flying)))

    monkeypatch.setattr(campaign_pool._Workers, "drain", drain_then_act)


def test_a_landing_that_raises_in_a_worker_is_named():
    with pytest.raises(
        CampaignLandingError,
        match=r"landing [12] of 2 \(seed 3000, (fusion|gps_only)\) failed in worker \d+: ConfigError",
    ):
        run_landing_campaign(1, 3, ("fusion", "gps_only"), tuning={"landing": {"no_such_key": 1.0}}, jobs=2)
    assert _no_workers_left()


def test_a_worker_that_dies_names_its_landing(monkeypatch):
    _on_first_start(monkeypatch, lambda pid: os.kill(pid, signal.SIGKILL))
    with pytest.raises(
        CampaignLandingError,
        match=r"died while flying landing [12] of 2 \(seed 300[01], fusion\) \(worker \d+, signal 9\)",
    ):
        run_landing_campaign(2, 3, ("fusion",), jobs=2)
    assert _no_workers_left()


def test_ctrl_c_stops_the_workers(monkeypatch):
    def interrupt(pid):
        raise KeyboardInterrupt

    _on_first_start(monkeypatch, interrupt)
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        run_landing_campaign(2, 3, ("fusion",), jobs=2)
    assert _no_workers_left(5.0)
    assert time.monotonic() - t0 < 15.0  # not waiting for the landings to finish
