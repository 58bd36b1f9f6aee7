"""The watched reel-in (winch.reel_check_s, companion.delivery.winch): a line that does not come in
at half the asked rate, or a winch reporting itself unhealthy, is a jam said CRITICAL; the reel-in
is tried reel_retries more times, then the sequence ends jammed (the mission lands where it is).
Off (reel_check_s = 0): a slow line gets reel_timeout_s, as before."""

from __future__ import annotations

from typing import Any

from companion.autopilot.component import SEVERITY_CRITICAL
from companion.autopilot.winch import MAV_WINCH_STATUS_HEALTHY, WinchAction, WinchStatus
from companion.config import WinchConfig
from companion.delivery.gcs import event_severity
from companion.delivery.winch import WinchSequence, WinchStep, WinchTick
from companion.events import EventKind, MissionEvent, Phase

BASE: dict[str, Any] = {"hover_height_m": 5.0, "slack_m": 0.3, "settle_s": 2.0, "reel_timeout_s": 60.0}


def _reeling(cfg: WinchConfig) -> tuple[WinchSequence, float]:
    """A sequence past its release, the reel-in of 5.3 m accepted at the returned time."""
    seq = WinchSequence(cfg, 1.0)
    seq.step(0.0, True, WinchStatus(0.0, 0.0, 0.0), True)
    t = 2.0
    assert seq.step(t, True, WinchStatus(t, 0.0, 0.0), True).command is not None
    seq.on_result(t, True)
    t = 13.0
    seq.step(t, True, WinchStatus(t, 5.3, 0.0), True)  # parcel down
    t += 0.05
    assert seq.step(t, True, WinchStatus(t, 5.3, 0.0), True).release
    seq.on_result(t, True)
    t += 1.1
    tick = seq.step(t, True, WinchStatus(t, 5.3, 0.0), True)
    assert tick.command is not None and tick.command.length_m == -5.3
    seq.on_result(t, True)
    return seq, t


def _run(
    seq: WinchSequence, t0: float, lengths: list[float], flags: int = MAV_WINCH_STATUS_HEALTHY
) -> list[tuple[float, WinchTick]]:
    """Reports at 5 Hz of the given lengths; the ticks' (time, tick) where anything happened."""
    out = []
    for k, length in enumerate(lengths):
        t = t0 + 0.2 * (k + 1)
        tick = seq.step(t, True, WinchStatus(t, length, 0.0, flags), True)
        if tick.command is not None:
            seq.on_result(t, True)
        if tick.critical or tick.command is not None or tick.done:
            out.append((t, tick))
        if tick.done:
            break
    return out


def test_a_line_that_stays_out_is_a_jam_tried_again_then_a_landing() -> None:
    seq, t = _reeling(WinchConfig(**BASE, reel_check_s=2.0, reel_retries=1))
    got = _run(seq, t, [5.3] * 60)
    # first window (2 s of reports after the first one): 0 m in, 0.50 m expected -> try 2
    (t1, first), (t2, second) = got[0], got[1]
    assert first.critical and "0.00 m in over 2.0 s, 0.50 m expected" in first.critical[0]
    assert "reel-in try 2 of 2" in first.critical[0] and first.command is None and not first.done
    assert second.command is not None and second.command.action is WinchAction.RELATIVE_LENGTH_CONTROL
    assert second.command.length_m == -5.3 and t2 > t1
    t3, last = got[-1]
    assert last.done and seq.jammed and seq.jams == 2
    assert "after 2 tries" in last.critical[0] and "landing where the vehicle is" in last.critical[0]
    assert 2.3 < t3 - t1 < 2.5  # the retry sent 0.2 s later, its own 2 s window from its first report
    assert seq.delivered  # released before the jam: on the pad
    assert seq.step_now is WinchStep.DONE


def test_a_line_coming_in_slowly_at_the_end_is_no_jam() -> None:
    """Length control slows the last part (WINCH_POS_P x the error): the window asks at most what
    is left above reeled_in_m."""
    seq, t = _reeling(WinchConfig(**BASE, reel_check_s=2.0))
    lengths, x = [], 5.3
    for _ in range(80):
        x -= 0.2 * min(0.5, x)  # 0.5 m/s, then the error decaying at 1/s
        lengths.append(x)
    got = _run(seq, t, lengths)
    assert got[-1][1].done and not seq.jammed and not any(tk.critical for _, tk in got)
    assert any("line reeled in" in s for s in got[-1][1].say)


def test_an_unhealthy_winch_is_a_jam_at_once_and_no_retries_lands() -> None:
    seq, t = _reeling(WinchConfig(**BASE, reel_check_s=2.0, reel_retries=0))
    got = _run(seq, t, [5.2], flags=0)
    assert got[0][1].done and seq.jammed
    assert "the winch reports itself unhealthy" in got[0][1].critical[0]


def test_off_by_default_a_stuck_line_waits_for_reel_timeout() -> None:
    seq, t = _reeling(WinchConfig(**BASE))
    got = _run(seq, t, [5.3] * 400)
    assert not any(tk.critical for _, tk in got) and not seq.jammed
    t_end, last = got[-1]
    assert last.done and t_end - t > 60.0 and "flying home as it is" in last.say[-1]


def test_the_jam_event_reaches_the_gcs_as_critical() -> None:
    ev = MissionEvent(1.0, EventKind.WINCH_JAM, Phase.WINCH, "the line will not reel in")
    assert event_severity(ev) == SEVERITY_CRITICAL
