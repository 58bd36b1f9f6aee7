"""fly_on_truth's moving pad (docs/moving-pad.md): the track's clock starts at the take-off and the
pad stops dead at the vehicle's first ground contact on truth (its descent stopped), the instant
between the last two samples from the sink rate."""

from __future__ import annotations

import time

import pytest

from companion.events import Phase
from companion.geometry.earth import GeoPoint
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import _TruthScore
from companion_sitl.pad_motion import PadTrack
from companion_sitl.params import SimPadMotionConfig

HOME = GeoPoint(-35.363261, 149.16523, 584.0)
LEVEL = (1.0, 0.0, 0.0, 0.0)


def _at(truth: MavlinkTruth, height_m: float, down_m_s: float) -> None:
    geo = (HOME.lat_deg, HOME.lon_deg, HOME.alt_amsl_m + height_m)
    truth.store_sample(list(LEVEL), geo, (0.0, 0.0, down_m_s), 0.0)


def test_the_pad_starts_with_the_take_off_and_stops_at_the_contact():
    truth = MavlinkTruth("udpin:127.0.0.1:0", origin=HOME)
    _at(truth, 0.0, 0.0)
    cfg = SimPadMotionConfig.model_validate({"speed_m_s": 2.0, "course_deg": 0.0, "start_s": 0.0, "accel_m_s2": 10.0})
    track = PadTrack(cfg, 10.0, 0.0)
    track.start_clock(None)
    score = _TruthScore(truth, (10.0, 0.0), track)
    score._move_pad(Phase.ARMING)
    assert track.origin_s is None  # stands until the take-off
    score._move_pad(Phase.TAKEOFF)
    assert track.origin_s == pytest.approx(time.monotonic(), abs=0.5)
    _at(truth, 0.02, 0.5)
    score._move_pad(Phase.TAKEOFF)
    _at(truth, 0.0, 0.0)
    score._move_pad(Phase.TAKEOFF)
    assert track.stopped_s is None  # never up yet: a take-off's first centimetres are no contact
    _at(truth, 5.0, 0.0)
    score._move_pad(Phase.OUTBOUND)
    _at(truth, 0.2, 0.5)
    score._move_pad(Phase.LANDING_PAD)
    assert track.stopped_s is None  # still sinking
    t0 = time.monotonic() - truth.age_s
    time.sleep(0.1)
    # stopped dead 8 cm below the take-off level (PX4 SIH's ground): 0.28 m at 0.5 m/s after t0
    _at(truth, -0.08, 0.0)
    score._move_pad(Phase.LANDING_PAD)
    assert track.stopped_s == pytest.approx(min(t0 + 0.28 / 0.5, time.monotonic()), abs=0.02)
    t = time.monotonic()
    stop = track.ne(track.stopped_s)
    assert track.ne(t + 100.0) == stop and track.velocity_ne(t + 100.0) == (0.0, 0.0)
    assert score.pad_at(t + 100.0) == stop
    assert score.contact_ne == pytest.approx((truth.pn, truth.pe))
