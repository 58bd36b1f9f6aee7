"""The mode story of the companion-death harness, from heartbeats whose arrival times are drawn."""

from __future__ import annotations

import random
from types import SimpleNamespace

from companion_firmware.companion_kill import mode_changes

NAMES = {6: "OFFBOARD", 4: "AUTO.LAND"}


def _beats(times_modes):
    return [(t, SimpleNamespace(custom_mode=m)) for t, m in times_modes]


def test_the_first_entry_is_the_mode_at_the_stop_even_when_the_first_beat_after_it_comes_at_once():
    # the CI failure of 2026-12-03: a heartbeat 0.01 s after the stop read as a change to OFFBOARD
    beats = _beats([(9.2, 6), (10.01, 6), (11.01, 6), (12.01, 4), (13.01, 4)])
    modes, failsafe = mode_changes(beats, 10.0, NAMES.__getitem__)
    assert modes == [(-0.8, "OFFBOARD"), (2.01, "AUTO.LAND")]
    assert failsafe == 2.01


def test_with_no_heartbeat_before_the_stop_no_change_is_claimed():
    modes, failsafe = mode_changes(_beats([(10.5, 4), (11.5, 4)]), 10.0, NAMES.__getitem__)
    assert modes == [(0.5, "AUTO.LAND")] and failsafe is None


def test_drawn_beat_phases_give_the_change_at_the_first_beat_in_the_new_mode():
    rng = random.Random(57)
    for _ in range(200):
        phase, t_stop, t_switch = rng.uniform(0, 1), rng.uniform(5, 6), rng.uniform(6.1, 9)
        beats = _beats([(phase + k, 6 if phase + k < t_switch else 4) for k in range(15)])
        modes, failsafe = mode_changes(beats, t_stop, NAMES.__getitem__)
        first_land = next(t for t, m in beats if m.custom_mode == 4)
        assert modes[0][1] == "OFFBOARD" and modes[0][0] <= 0.0
        assert [m for _, m in modes] == ["OFFBOARD", "AUTO.LAND"]
        assert failsafe == round(first_land - t_stop, 2)
