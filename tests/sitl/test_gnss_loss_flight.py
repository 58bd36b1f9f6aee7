"""GNSS lost on the embedded simulator's ArduCopter profile (sitl/gnss_loss.py, docs/external-nav.md),
as the real ArduCopter SITL behaves: near the pad with [external_nav] the autopilot navigates on the
fused pose and the delivery lands and releases on the pad; without it, or out of camera and UWB
range, its EKF failsafe lands the vehicle 8.1 s after the loss and nothing is released. The px4-sih
profile the same way with PX4's figures: EKF2 fuses the pose without a switch, its failsafe
(OFFBOARD to ALTCTL) comes 5.3 s after the loss."""

from __future__ import annotations

import math

import pytest

from companion.config import shipped_params_path
from companion.events import Phase
from companion_lab.demo import run_demo
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.flight

PAD_OFFSET = (0.5, -0.4)  # the pad 0.64 m from where the parameters put it: GPS alone misses it


def _config(external_nav: bool, height_m: float = 8.0, profile: str = "arducopter-sitl"):  # type: ignore[no-untyped-def]
    return load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "mission": {"return_home": False, "height_m": height_m, "ready_timeout_s": 120.0},
            "landing": {"policy": {"require_pad_lock": True, "hold_s": 2.0, "descent_tries": 2}},
            "external_nav": {"enabled": external_nav},
            "sim": {"profile": profile, "seed": 4, "pad_offset_m": PAD_OFFSET},
        },
    )


def _cut_gnss(height_m: float, near_pad_m: float | None, phase: Phase | None = None):  # type: ignore[no-untyped-def]
    """An on_tick that switches the GPS off once: below ``height_m`` on the way down within
    ``near_pad_m`` of the true pad, or (``phase``) as soon as the mission is in ``phase``."""
    state = {"above": False, "cut_s": math.nan}

    def tick(shell, out) -> None:  # type: ignore[no-untyped-def]
        v = shell.autopilot.vehicle
        if math.isfinite(state["cut_s"]):
            return
        h = -v.pd
        state["above"] = state["above"] or h > height_m + 0.5
        pn, pe = v.pad_true_ned
        near = near_pad_m is None or math.hypot(v.pn - pn, v.pe - pe) <= near_pad_m
        if (phase is not None and shell.mission.phase is phase and h >= height_m) or (
            phase is None and state["above"] and near and h <= height_m
        ):
            v.lose_gnss()
            state["cut_s"] = v.time_s

    return tick, state


def test_gnss_lost_at_3_m_near_the_pad_lands_and_releases_on_it() -> None:
    tick, state = _cut_gnss(3.0, near_pad_m=6.0)
    r = run_demo(_config(external_nav=True), on_tick=tick)
    assert math.isfinite(state["cut_s"])
    assert r.delivered, r.failure
    assert r.pad_landing_error_m <= 0.10, r.pad_landing_error_m
    assert any("EKF source set 2" in e[3] for e in r.events), r.events
    assert not any("EKF Failsafe" in e[3] for e in r.events)


def test_gnss_lost_at_12_m_without_external_nav_the_ekf_failsafe_lands_without_a_release() -> None:
    # 12 m in a 13 m approach: more than the failsafe's 8.1 s before the touchdown
    tick, state = _cut_gnss(12.0, near_pad_m=15.0)
    r = run_demo(_config(external_nav=False, height_m=13.0), on_tick=tick)
    assert math.isfinite(state["cut_s"])
    assert not r.delivered and "pilot took over (land)" in r.failure, r.failure
    assert not any(e[1] == "released" for e in r.events), r.events


def test_gnss_lost_in_the_cruise_is_left_to_the_autopilot_failsafe_never_a_release() -> None:
    tick, state = _cut_gnss(7.0, near_pad_m=None, phase=Phase.OUTBOUND)
    r = run_demo(_config(external_nav=True), on_tick=tick)
    assert math.isfinite(state["cut_s"])
    assert not r.delivered and "pilot took over (land)" in r.failure, r.failure
    assert any("out of camera and UWB range" in e[3] for e in r.events), r.events
    assert not any("EKF source set 2" in e[3] and "navigates" in e[3] for e in r.events)
    assert not any(e[1] == "released" for e in r.events), r.events


def test_px4_sih_gnss_lost_at_3_m_near_the_pad_lands_and_releases_on_it_without_a_switch() -> None:
    tick, state = _cut_gnss(3.0, near_pad_m=6.0)
    r = run_demo(_config(external_nav=True, profile="px4-sih"), on_tick=tick)
    assert math.isfinite(state["cut_s"])
    assert r.delivered, r.failure
    assert r.pad_landing_error_m <= 0.10, r.pad_landing_error_m
    assert any("EKF2 external vision" in e[3] for e in r.events), r.events
    assert not any(e[1] == "pilot_takeover" for e in r.events), r.events


def test_px4_sih_gnss_lost_at_8_m_without_external_nav_px4_takes_it_without_a_release() -> None:
    # 8 m in a 13 m approach: more than PX4's 5.3 s before the touchdown; out of OFFBOARD into ALTCTL
    tick, state = _cut_gnss(8.0, near_pad_m=15.0)
    r = run_demo(_config(external_nav=False, height_m=13.0, profile="px4-sih"), on_tick=tick)
    assert math.isfinite(state["cut_s"])
    assert not r.delivered and "pilot took over (manual)" in r.failure, r.failure
    took = next(e[0] for e in r.events if e[1] == "pilot_takeover")
    assert 5.3 <= took - state["cut_s"] <= 6.0, (took, state["cut_s"])  # PX4's delay, then the mode seen
    assert not any(e[1] == "released" for e in r.events), r.events
