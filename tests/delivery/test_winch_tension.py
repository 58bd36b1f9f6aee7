"""The winch sequence reading the line's tension (winch.tension_sensing, a load-cell winch): the
parcel down when the line goes slack, a parcel caught on the way down, one hanging short of the
ground, a line that never carried it, one still on the hook after the release; and the length
rule when the winch reports no tension."""

from __future__ import annotations

import math

import pytest

from companion.autopilot.winch import WinchStatus
from companion.config import WinchConfig
from companion.delivery.winch import SLACK_CONFIRM_S, WinchSequence, WinchStep

CFG = WinchConfig(
    hover_height_m=5.0, slack_m=0.3, settle_s=0.0, payout_timeout_s=30.0, reel_timeout_s=30.0, tension_sensing=True
)
KG = 0.5  # the parcel


def _paying_out(cfg: WinchConfig = CFG) -> tuple[WinchSequence, float]:
    seq = WinchSequence(cfg, 1.0)
    tick = seq.step(0.0, True, WinchStatus(0.0, 0.0, 0.0, tension_kg=0.0), True)
    assert tick.command is not None  # settle_s 0: the payout at once
    seq.on_result(0.0, True)
    return seq, 0.0


def _lower(seq: WinchSequence, t: float, to_m: float, kg: float, dt: float = 0.25) -> tuple[float, list[str]]:
    """Reports every ``dt`` as the line pays out at 0.5 m/s up to ``to_m`` carrying ``kg``."""
    said: list[str] = []
    length = 0.0
    while length < to_m and seq.step_now is WinchStep.PAYOUT:
        t += dt
        length = min(to_m, length + 0.5 * dt)
        said += seq.step(t, True, WinchStatus(t, length, 0.5, tension_kg=kg), True).say
    return t, said


def _hold(seq: WinchSequence, t: float, length: float, kg: float, seconds: float) -> tuple[float, list[str]]:
    said: list[str] = []
    end = t + seconds
    while t < end:
        t += 0.25
        said += seq.step(t, True, WinchStatus(t, length, 0.0, tension_kg=kg), True).say
    return t, said


def test_the_parcel_is_down_when_the_line_goes_slack_and_released_once_it_comes_up_light() -> None:
    seq, t = _paying_out()
    t, _ = _lower(seq, t, 4.9, KG)  # hanging all the way down
    assert seq.step_now is WinchStep.PAYOUT
    t, said = _hold(seq, t, 4.95, 0.0, 0.25)  # touched down: slack for an instant only
    assert seq.step_now is WinchStep.PAYOUT, said
    t, said = _hold(seq, t, 5.0, 0.0, SLACK_CONFIRM_S)
    assert seq.step_now is WinchStep.RELEASE and any("went slack at 4.95 m" in s for s in said), said
    t += 0.25
    assert seq.step(t, True, WinchStatus(t, 5.0, 0.0, tension_kg=0.0), True).release
    seq.on_result(t, True)
    t += 1.1
    tick = seq.step(t, True, WinchStatus(t, 5.0, 0.0, tension_kg=0.0), True)
    assert tick.command is not None and tick.command.length_m == -5.0  # reeling in
    assert not seq.delivered  # not yet: the line must come up light first
    seq.on_result(t, True)
    t, said = _hold(seq, t, 4.7, 0.0, 0.5)
    assert not seq.delivered
    t, said = _hold(seq, t, 4.39, 0.0, 0.25)  # 0.61 m in, slack all the way: left on the pad
    assert seq.delivered and seq.failure == "" and any("came up light" in s for s in said), said
    tick = seq.step(t + 5.0, True, WinchStatus(t + 5.0, 0.05, -0.5, tension_kg=0.0), True)
    assert tick.done and seq.delivered


def test_a_parcel_caught_on_the_way_down_is_not_released() -> None:
    seq, t = _paying_out()
    t, _ = _lower(seq, t, 2.5, KG)  # 2.5 m below the vehicle, 2.5 m above the pad: slack
    t, said = _hold(seq, t, 2.6, 0.0, 1.0)
    assert seq.step_now is WinchStep.REEL and not seq.delivered
    assert seq.failure.startswith("the parcel caught on the way down: the line went slack at 2.6"), seq.failure
    assert any("reeling in, flying home with the parcel" in s for s in said), said


def test_a_parcel_hanging_at_the_lines_full_length_is_not_released() -> None:
    seq, t = _paying_out()
    t, _ = _lower(seq, t, 5.3, KG)  # the line out to hover height + slack, still carrying it
    assert seq.step_now is WinchStep.REEL and not seq.delivered
    assert seq.failure.startswith("the parcel hangs short of the ground: the line is out 5.2"), seq.failure


def test_a_line_that_never_carried_the_parcel_is_not_a_delivery() -> None:
    seq, t = _paying_out()
    t, _ = _lower(seq, t, 5.3, 0.0)
    assert seq.step_now is WinchStep.REEL and seq.failure.startswith("the line never carried the parcel")


def test_a_parcel_still_on_the_hook_comes_home() -> None:
    seq, t = _paying_out()
    t, _ = _lower(seq, t, 5.0, KG)
    t, _ = _hold(seq, t, 5.0, 0.0, 0.75)  # slack from the first report, confirmed 0.5 s later
    assert seq.step_now is WinchStep.RELEASE
    t += 0.25
    assert seq.step(t, True, WinchStatus(t, 5.0, 0.0, tension_kg=0.0), True).release
    seq.on_result(t, True)  # the autopilot moved the servo
    t += 1.1
    seq.step(t, True, WinchStatus(t, 5.0, 0.0, tension_kg=0.0), True)
    seq.on_result(t, True)
    t, _ = _hold(seq, t, 4.75, KG, 0.25)  # the slack taken up: it weighs the parcel again
    assert not seq.delivered and seq.failure.startswith("parcel not released: the line took its load again")
    assert seq.step_now is WinchStep.REEL  # coming in with it
    tick = seq.step(t + 10.0, True, WinchStatus(t + 10.0, 0.05, -0.5, tension_kg=KG), True)
    assert tick.done and not seq.delivered


def test_a_winch_that_reports_no_tension_is_judged_on_the_length_said_once() -> None:
    seq, t = _paying_out()
    said: list[str] = []
    for length in (1.0, 3.0, 5.25):
        t += 2.0
        said += seq.step(t, True, WinchStatus(t, length, 0.5, tension_kg=math.nan), True).say
    assert seq.step_now is WinchStep.RELEASE
    assert sum("reports no tension" in s for s in said) == 1, said


def test_without_tension_sensing_a_tension_report_changes_nothing() -> None:
    cfg = CFG.model_copy(update={"tension_sensing": False})
    seq, t = _paying_out(cfg)
    t, _ = _lower(seq, t, 5.3, KG)  # taut at full length: the length rule releases
    assert seq.step_now is WinchStep.RELEASE and seq.failure == ""


def test_the_light_check_must_reach_past_the_slack() -> None:
    with pytest.raises(ValueError, match="light_check_m"):
        WinchConfig(tension_sensing=True, slack_m=0.8, light_check_m=0.6)
