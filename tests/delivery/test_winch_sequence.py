"""The winch delivery's sequence (companion.delivery.winch): payout, parcel down, release, reel
in; a refused command or a line that does not pay out ends with the line in and the parcel home."""

from __future__ import annotations

import math

import pytest

from companion.autopilot.types import Wind
from companion.autopilot.winch import WinchAction, WinchStatus
from companion.config import WinchConfig
from companion.delivery.winch import WinchSequence, WinchStep, WindCorrection

CFG = WinchConfig(hover_height_m=5.0, slack_m=0.3, settle_s=2.0, payout_timeout_s=20.0, reel_timeout_s=20.0)


def _status(t: float, length_m: float) -> WinchStatus:
    return WinchStatus(t, length_m, 0.0)


def _settled(seq: WinchSequence) -> float:
    """Ready over the pad until the payout goes out; returns the time it did."""
    t = 0.0
    assert seq.step(t, True, _status(t, 0.0), True).command is None
    t = 1.9
    assert seq.step(t, True, _status(t, 0.0), True).command is None  # not yet settle_s
    t = 2.0
    tick = seq.step(t, True, _status(t, 0.0), True)
    assert tick.command is not None
    assert tick.command.action is WinchAction.RELATIVE_LENGTH_CONTROL
    assert tick.command.length_m == 5.3 and tick.command.rate_m_s == CFG.payout_rate_m_s
    return t


def test_settle_restarts_when_the_hover_is_not_ready() -> None:
    seq = WinchSequence(CFG, 1.0)
    seq.step(0.0, True, None, True)
    seq.step(1.5, False, None, True)  # a gust: off the centre
    assert seq.step(3.0, True, None, True).command is None
    assert seq.step(5.0, True, None, True).command is not None  # 2 s after it was ready again


def test_parcel_down_release_reel_in_done() -> None:
    seq = WinchSequence(CFG, 1.0)
    t = _settled(seq)
    seq.on_result(t, True)
    assert seq.paid_out and seq.step_now is WinchStep.PAYOUT
    t += 5.0
    assert not seq.step(t, True, _status(t, 2.5), True).release
    t += 6.0
    tick = seq.step(t, True, _status(t, 5.21), True)  # within length_tolerance_m of 5.3
    assert seq.step_now is WinchStep.RELEASE and any("parcel down" in s for s in tick.say)
    t += 0.05
    assert seq.step(t, True, _status(t, 5.3), True).release
    seq.on_result(t, True)
    t += 0.5
    assert seq.step(t, True, _status(t, 5.3), True).command is None  # the actuator's time: 1 s
    t += 0.6
    tick = seq.step(t, True, _status(t, 5.3), True)
    assert seq.delivered and tick.command is not None
    assert tick.command.length_m == -5.3 and tick.command.rate_m_s == CFG.reel_rate_m_s
    seq.on_result(t, True)
    t += 10.0
    assert not seq.step(t, True, _status(t, 0.5), True).done
    t += 1.0
    tick = seq.step(t, True, _status(t, 0.08), True)
    assert tick.done and seq.delivered and seq.failure == ""


def test_refused_payout_reels_in_and_ends_with_the_parcel() -> None:
    seq = WinchSequence(CFG, 1.0)
    t = _settled(seq)
    seq.on_result(t, False, "winch (relative_length_control, +5.30 m): FAILED")
    assert seq.failure.startswith("the winch refused the payout") and not seq.delivered
    tick = seq.step(t + 0.05, True, None, True)
    assert tick.command is not None and tick.command.length_m == -5.3  # no report: from the target
    seq.on_result(t + 0.1, False, "FAILED")
    tick = seq.step(t + 0.15, True, None, True)
    assert tick.done and not seq.delivered
    assert seq.failure.startswith("the winch refused the payout")  # the first reason stays


def test_line_that_does_not_pay_out_times_out_then_reels_in() -> None:
    seq = WinchSequence(CFG, 1.0)
    t = _settled(seq)
    seq.on_result(t, True)
    assert seq.step(t + 19.9, True, _status(t + 19.9, 0.4), True).command is None
    tick = seq.step(t + 20.1, True, _status(t + 20.1, 0.4), True)
    assert "the line did not pay out: line 0.40 m of 5.30 m after 20.0 s" in seq.failure
    assert tick.command is not None and tick.command.length_m == -0.4 and not tick.release
    seq.on_result(t + 20.2, True)
    tick = seq.step(t + 21.0, True, _status(t + 21.0, 0.0), True)
    assert tick.done and not seq.delivered


def test_refused_release_keeps_the_parcel_and_reels_it_in() -> None:
    seq = WinchSequence(CFG, 1.0)
    t = _settled(seq)
    seq.on_result(t, True)
    seq.step(t + 11.0, True, _status(t + 11.0, 5.3), True)
    assert seq.step(t + 11.05, True, _status(t + 11.05, 5.3), True).release
    seq.on_result(t + 11.1, False, "release (gripper): FAILED")
    assert seq.failure.startswith("parcel not released") and not seq.delivered
    tick = seq.step(t + 11.2, True, _status(t + 11.2, 5.3), True)
    assert tick.command is not None and tick.command.length_m == -5.3


def test_reel_in_that_never_finishes_ends_after_its_timeout() -> None:
    seq = WinchSequence(CFG, 0.0)
    t = _settled(seq)
    seq.on_result(t, True)
    seq.step(t + 11.0, True, _status(t + 11.0, 5.3), True)
    seq.step(t + 11.05, True, _status(t + 11.05, 5.3), True)
    seq.on_result(t + 11.1, True)
    tick = seq.step(t + 11.2, True, _status(t + 11.2, 5.3), True)
    assert tick.command is not None
    seq.on_result(t + 11.2, True)
    tick = seq.step(t + 31.3, True, _status(t + 31.3, 5.3), True)
    assert tick.done and seq.delivered and seq.failure == ""
    assert any("not back in after 20.0 s (5.30 m still out)" in s for s in tick.say)


def test_wind_correction_hovers_upwind_by_the_parcels_drift() -> None:
    cfg = WinchConfig(hover_height_m=5.0, wind_drift_s_m=0.03, wind_filter_s=2.0)
    wc = WindCorrection(cfg)
    # the air moves north at 4 m/s: the parcel hangs 0.03 * 5 * 4 = 0.6 m north; hover 0.6 m south
    assert wc.offset_ne_m(0.0, Wind(0.0, 4.0, 0.0)) == pytest.approx((-0.6, 0.0))
    # a step to 0 m/s is followed over wind_filter_s: after one time constant 1/e of it remains
    n, _ = wc.offset_ne_m(2.0, Wind(2.0, 0.0, 0.0))
    assert n == pytest.approx(-0.6 * math.exp(-1.0))
    assert WindCorrection(WinchConfig()).offset_ne_m(0.0, Wind(0.0, 4.0, 0.0)) == (0.0, 0.0)  # off by default
    assert wc.offset_ne_m(3.0, None) == (0.0, 0.0)  # no estimate: over the centre


def test_stop_reels_in_from_the_payout_and_ends_at_once_before_it() -> None:
    seq = WinchSequence(CFG, 1.0)
    assert seq.stop(0.5, "ground command from gcs: return")  # settling: nothing is out
    assert seq.step(0.6, True, None, True).done and seq.failure.startswith("ground command")
    seq = WinchSequence(CFG, 1.0)
    t = _settled(seq)
    seq.on_result(t, True)
    assert seq.stop(t + 3.0, "ground command from gcs: return")
    tick = seq.step(t + 3.05, True, _status(t + 3.05, 1.5), True)
    assert tick.command is not None and tick.command.length_m == -1.5  # in from where it is
    assert not seq.stop(t + 3.1, "again")  # already coming in
    seq.on_result(t + 3.1, True)
    assert seq.step(t + 7.0, True, _status(t + 7.0, 0.05), True).done and not seq.delivered


def test_a_line_still_paying_out_is_stopped_before_the_reel_in() -> None:
    seq = WinchSequence(CFG, 1.0)
    t = _settled(seq)
    seq.on_result(t, True)
    seq.stop(t + 3.0, "ground command from gcs: return")
    tick = seq.step(t + 3.05, True, WinchStatus(t + 3.0, 1.5, 0.5), True)
    assert tick.command is not None and tick.command.action is WinchAction.RATE_CONTROL
    assert tick.command.rate_m_s == 0.0 and any("stopping the line first" in s for s in tick.say)
    seq.on_result(t + 3.1, True)
    # a report from before the stop's answer is not the length it stopped at
    assert seq.step(t + 3.15, True, WinchStatus(t + 3.05, 1.55, 0.5), True).command is None
    tick = seq.step(t + 3.3, True, WinchStatus(t + 3.25, 1.58, 0.0), True)
    assert tick.command is not None and tick.command.length_m == -1.58
    seq.on_result(t + 3.35, True)
    assert seq.step(t + 8.0, True, WinchStatus(t + 8.0, 0.0, 0.0), True).done


def test_a_refused_stop_ends_the_sequence_with_the_line_as_it_is() -> None:
    seq = WinchSequence(CFG, 1.0)
    t = _settled(seq)
    seq.on_result(t, True)
    seq.stop(t + 3.0, "ground command from gcs: return")
    seq.step(t + 3.05, True, WinchStatus(t + 3.0, 1.5, 0.5), True)
    seq.on_result(t + 3.1, False, "FAILED")
    tick = seq.step(t + 3.15, True, WinchStatus(t + 3.1, 1.55, 0.5), True)
    assert tick.done and any("refused to stop the line" in s for s in tick.say)
