"""The parcel hung on a real firmware's reported winch line (companion_firmware.truth_parcel),
stepped against a scripted truth link: it follows the reported length down to the ground under
the vehicle, and stays there once the gripper output reaches its release PWM."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from companion_firmware.truth_parcel import ParcelOnTruth


class _Truth:
    """A hovering vehicle at 5 m whose winch pays out at 0.5 m/s from t = 1 s to 5.3 m."""

    watch = frozenset({"WINCH_STATUS", "SERVO_OUTPUT_RAW"})

    def __init__(self) -> None:
        self.t = 0.0
        self.grip_pwm = 1900
        self.reel_from: float | None = None
        self.pn, self.pe, self.pd, self.vn, self.ve, self.vd = 2.0, -1.0, -5.0, 0.0, 0.0, 0.0

    def length(self) -> float:
        out = min(5.3, max(0.0, 0.5 * (self.t - 1.0)))
        if self.reel_from is not None:
            out = max(0.0, out - 0.5 * (self.t - self.reel_from))
        return out

    def watched_messages(self, kind: str, since: float = -1e9) -> list[tuple[float, object]]:
        if kind == "WINCH_STATUS":
            return [(self.t, SimpleNamespace(line_length=self.length()))]
        return [(self.t, SimpleNamespace(servo9_raw=self.grip_pwm))]


def _run_to(p: ParcelOnTruth, tr: _Truth, until_s: float) -> tuple[float, float, float] | None:
    where = None
    while tr.t < until_s:
        tr.t = round(tr.t + 1 / 30, 9)
        where = p.bottom_ned()
    return where


def test_the_parcel_follows_the_reported_line_to_the_ground_and_stays_released() -> None:
    tr = _Truth()
    p = ParcelOnTruth(tr, release_output=9, release_pwm=1100, clock=lambda: tr.t)  # type: ignore[arg-type]
    assert _run_to(p, tr, 0.9) is None  # in its bay: not drawn
    mid = _run_to(p, tr, 6.0)  # 2.5 m out
    assert mid is not None and mid[2] == pytest.approx(-5.0 + 2.5, abs=0.05)
    assert (mid[0], mid[1]) == pytest.approx((2.0, -1.0), abs=0.01)  # straight under a still vehicle
    down = _run_to(p, tr, 13.0)  # 5.3 m out: on the ground with 0.3 m of slack
    assert down == pytest.approx((2.0, -1.0, 0.0), abs=0.01)
    td = p.parcel.touchdown
    assert td is not None and td.vertical_speed_m_s == pytest.approx(0.5, abs=0.05)  # lowered at the payout rate
    tr.grip_pwm = 1100  # the gripper opens
    _run_to(p, tr, 14.0)
    tr.reel_from = 14.0
    assert _run_to(p, tr, 30.0) == pytest.approx((2.0, -1.0, 0.0), abs=0.01)  # left on the ground


def test_reeled_in_before_the_release_it_comes_up_again() -> None:
    tr = _Truth()
    p = ParcelOnTruth(tr, release_output=9, release_pwm=1100, clock=lambda: tr.t)  # type: ignore[arg-type]
    _run_to(p, tr, 13.0)
    tr.reel_from = 13.0
    up = _run_to(p, tr, 20.0)  # 3.5 m reeled in: 1.8 m of line, hanging 3.2 m above the ground
    assert up is not None and up[2] == pytest.approx(-5.0 + 1.8, abs=0.05)
    assert _run_to(p, tr, 26.0) is None  # back in its bay


def test_a_truth_link_not_watching_the_winch_is_refused() -> None:
    tr = SimpleNamespace(watch=frozenset({"SERVO_OUTPUT_RAW"}))
    with pytest.raises(ValueError, match="must watch WINCH_STATUS"):
        ParcelOnTruth(tr, 9, 1100)  # type: ignore[arg-type]
