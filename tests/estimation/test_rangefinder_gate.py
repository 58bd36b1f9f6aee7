"""The rangefinder gate (companion.estimation.rangefinder): every rejection reason, the hold of the
last correction, and properties over seeded random readings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from companion.autopilot.types import MAV_SENSOR_ROTATION_PITCH_270, RangefinderReading
from companion.config import RangefinderConfig
from companion.estimation.rangefinder import RangefinderGate, Rejection

CFG = RangefinderConfig(enabled=True)


def reading(t: float, d: float, lo: float = 0.2, hi: float = 7.0, orient: int = 25, q: int | None = None):
    return RangefinderReading(t, d, lo, hi, orient, q)


def test_a_good_reading_confirmed_by_the_next_is_the_height_tilt_corrected() -> None:
    g = RangefinderGate(CFG)
    roll, pitch = math.radians(10.0), math.radians(-5.0)
    h, why = g.judge(reading(0.9, 2.05), 0.95, 2.55, roll, pitch)
    assert h is None and why is Rejection.UNCONFIRMED  # the first after none
    h, why = g.judge(reading(1.0, 2.0), 1.05, 2.5, roll, pitch)
    assert why is None and h == pytest.approx(2.0 * math.cos(roll) * math.cos(pitch))
    assert g.accepted == 1 and g.rejected == {Rejection.UNCONFIRMED: 1}


@pytest.mark.parametrize(
    ("r", "now", "est_h", "tilt_deg", "why"),
    [
        (reading(1.0, 2.0, orient=0), 1.0, 2.0, 0.0, Rejection.NOT_DOWNWARD),  # forward-looking
        (reading(1.0, 2.0, q=0), 1.0, 2.0, 0.0, Rejection.LOW_QUALITY),  # below min_quality_pct 1
        (reading(1.0, 2.0), 1.0 + CFG.max_age_s + 0.01, 2.0, 0.0, Rejection.STALE),
        (reading(1.0, 0.1), 1.0, 0.1, 0.0, Rejection.OUT_OF_RANGE),  # below RNGFND1_MIN
        (reading(1.0, 7.0), 1.0, 3.5, 0.0, Rejection.OUT_OF_RANGE),  # at the maximum: no echo
        (reading(1.0, 2.0), 1.0, 2.0, CFG.max_tilt_deg + 1.0, Rejection.TILTED),
        (reading(1.0, 5.0), 1.0, CFG.below_height_m + 0.1, 0.0, Rejection.TOO_HIGH),
        (reading(1.0, 0.5), 1.0, 0.5 + CFG.max_disagreement_m + 0.1, 0.0, Rejection.INCONSISTENT),
    ],
)
def test_each_rejection_is_counted_by_its_reason(r, now, est_h, tilt_deg, why) -> None:  # type: ignore[no-untyped-def]
    g = RangefinderGate(CFG)
    # a reading before that would confirm it: only this reason rejects it
    g._candidate = (r.distance_m - est_h, r.time_s - 0.1)
    h, got = g.judge(r, now, est_h, math.radians(tilt_deg), 0.0)
    assert h is None and got is why
    assert g.rejected == {why: 1} and g.accepted == 0
    # the estimate's height is flown: no reading used yet, nothing to hold
    assert g.height(r, now, est_h, math.radians(tilt_deg), 0.0) == est_h


def test_a_jump_against_the_estimate_is_rejected_and_the_correction_held() -> None:
    g = RangefinderGate(CFG)
    # the estimate reads 1.2 m high (PX4 SIH): the rangefinder's 2.0 m is used, offset -1.2 m
    assert g.height(reading(-0.1, 2.05), -0.1, 3.25, 0.0, 0.0) == 3.25  # unconfirmed: the estimate's
    assert g.height(reading(0.0, 2.0), 0.0, 3.2, 0.0, 0.0) == pytest.approx(2.0)
    # a leg in the beam: 0.3 m while the estimate moved 0.05 m down
    h, why = g.judge(reading(0.1, 0.3), 0.1, 3.15, 0.0, 0.0)
    assert h is None and why is Rejection.JUMP and g.rejected[Rejection.JUMP] == 1
    # meanwhile the estimate corrected by the last offset is flown
    assert g.height(reading(0.1, 0.3), 0.1, 3.15, 0.0, 0.0) == pytest.approx(3.15 - 1.2)
    assert g.rejected[Rejection.JUMP] == 1  # the same reading judged again is counted once
    # the next true reading jumps back from the spike: not used either
    assert g.judge(reading(0.2, 1.9), 0.2, 3.1, 0.0, 0.0) == (None, Rejection.JUMP)
    # the descent goes on: a reading consistent with the one before and the estimate's motion is used
    assert g.height(reading(0.3, 1.85), 0.3, 3.05, 0.0, 0.0) == pytest.approx(1.85)
    assert g.rejected == {Rejection.UNCONFIRMED: 1, Rejection.JUMP: 2} and g.accepted == 2


def test_a_leg_staying_in_the_beam_is_rejected_while_the_last_correction_is_held() -> None:
    g = RangefinderGate(CFG)
    g.height(reading(0.0, 2.0), 0.0, 3.2, 0.0, 0.0)
    assert g.height(reading(0.1, 1.95), 0.1, 3.15, 0.0, 0.0) == pytest.approx(1.95)
    for k in range(2, 10):  # 0.3 m, steady: agrees with the reading before, not with the one used
        t = 0.1 * k
        assert g.judge(reading(t, 0.3), t, 3.2 - 0.05 * k, 0.0, 0.0)[1] is Rejection.JUMP
    assert g.rejected[Rejection.JUMP] == 8


def test_below_the_minimum_range_the_correction_is_held_for_hold_s_then_dropped() -> None:
    g = RangefinderGate(CFG)
    g.height(reading(-0.1, 0.55), -0.1, 1.75, 0.0, 0.0)
    assert g.height(reading(0.0, 0.5), 0.0, 1.7, 0.0, 0.0) == pytest.approx(0.5)  # offset -1.2 m
    at_ground = reading(0.3, 0.1)  # below RNGFND1_MIN 0.2 m
    assert g.height(at_ground, 0.3, 1.3, 0.0, 0.0) == pytest.approx(0.1)
    assert g.rejected[Rejection.OUT_OF_RANGE] == 1
    later = reading(CFG.hold_s + 0.5, 0.1)
    assert g.height(later, CFG.hold_s + 0.5, 1.2, 0.0, 0.0) == 1.2  # hold over: the estimate alone


def test_a_reading_gone_stale_since_it_was_used_is_counted_stale_once() -> None:
    g = RangefinderGate(CFG)
    g.judge(reading(-0.1, 2.0), -0.1, 2.0, 0.0, 0.0)
    r = reading(0.0, 2.0)
    assert g.judge(r, 0.0, 2.0, 0.0, 0.0)[1] is None
    assert g.judge(r, 0.05, 2.0, 0.0, 0.0)[1] is None  # the same reading, still fresh: counted once
    assert g.accepted == 1
    assert g.judge(r, 1.0, 2.0, 0.0, 0.0)[1] is Rejection.STALE  # the sensor stopped
    assert g.judge(r, 1.1, 2.0, 0.0, 0.0)[1] is Rejection.STALE
    assert g.rejected == {Rejection.UNCONFIRMED: 1, Rejection.STALE: 1}


def test_nothing_received_flies_the_estimate() -> None:
    g = RangefinderGate(CFG)
    assert g.height(None, 5.0, 1.5, 0.0, 0.0) == 1.5
    assert g.accepted == 0 and not g.rejected


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(seed=st.integers(0, 2**32 - 1))
@example(seed=13419180)  # two spikes around rejected readings once confirmed each other
def test_properties_over_seeded_random_readings(seed: int) -> None:
    """A descent from 3 m with an estimate biased by up to +-1.5 m, readings with noise, spikes
    (a leg, the parcel), drop-outs, tilt and the ground below the minimum range: whatever the gate
    says, a reading it uses is within the sensor's range, fresh, downward, consistent, and the
    spike (never two in a row) is never used; every reading is either used or rejected once."""
    rng = np.random.default_rng(seed)
    cfg = RangefinderConfig(enabled=True, max_jump_m=float(rng.uniform(0.2, 1.0)))
    g = RangefinderGate(cfg)
    bias = float(rng.uniform(-1.5, 1.5))
    noise = 0.02
    judged: set[float] = set()
    spiked = False
    used = 0
    for k in range(60):
        t = 0.1 * k
        true_h = max(0.0, 3.0 - 0.05 * k)
        est_h = true_h + bias + float(rng.normal(0.0, 0.02))
        tilt = math.radians(float(rng.uniform(0.0, 30.0)))
        d = true_h / math.cos(tilt) + float(rng.uniform(-noise, noise))
        spike = not spiked and rng.uniform() < 0.1  # never two in a row
        spiked = spike
        if spike:
            d = float(rng.uniform(0.0, 0.4))  # a leg or the parcel in the beam
        orient = MAV_SENSOR_ROTATION_PITCH_270 if rng.uniform() > 0.05 else 0
        r = RangefinderReading(t - float(rng.uniform(0.0, 0.8)), d, 0.2, 7.0, orient)
        h, why = g.judge(r, t, est_h, tilt, 0.0)
        judged.add(r.time_s)
        assert (h is None) != (why is None)
        if h is not None:
            assert 0.2 <= d < 7.0 and t - r.time_s <= cfg.max_age_s and orient == 25
            assert abs(h - est_h) <= cfg.max_disagreement_m
            assert tilt <= math.radians(cfg.max_tilt_deg) + 1e-12
            # a spike (one farther off than a jump) is never used: every reading used is a true
            # one (tilt-corrected, with its noise), or a spike within max_jump_m of it
            far = abs(d * math.cos(tilt) - true_h) > cfg.max_jump_m + 0.2
            assert not (spike and far)
            assert abs(h - true_h) <= (cfg.max_jump_m + 0.2 if spike else noise * math.cos(tilt) + 1e-9)
            used += 1
        flown = g.height(r, t, est_h, tilt, 0.0)
        # the height flown: the reading, the estimate corrected by a used one's offset (a true
        # reading's, or a spike's within max_jump_m), or the estimate
        assert abs(flown - true_h) <= max(abs(est_h - true_h), cfg.max_jump_m + 0.3)
    assert g.accepted == used and g.accepted + sum(g.rejected.values()) == len(judged)
