"""The Dart cyber-pilot on real ArduCopter 4.7 SITL: RC_CHANNELS_OVERRIDE added to the pilot's
sticks in ALT_HOLD and in STABILIZE, the pilot's switch giving control back, both seen at the vehicle.

The pilot's transmitter is the SITL's RC input (UDP 5501); the forward camera renders the wall
marker from SIM_STATE truth (companion_firmware.dart_arducopter).
"""

from __future__ import annotations

import numpy as np

from companion.dart.mission import DartMissionConfig, DartPhase
from companion_firmware.dart_arducopter import fly_dart_arducopter_modes
from companion_sitl.dart_sim import DartParams

MODES = {"ALT_HOLD": 2, "STABILIZE": 0}


async def test_dart_hovers_approaches_and_hands_back_on_the_switch_in_alt_hold_and_stabilize(ardupilot_root, tmp_path):
    """dart sec. 5 on the firmware, once in each of the pilot's modes on one boot (the pilot takes
    the sticks back, selects the next mode and switches the cyber-pilot on again): hover at 4 m
    from the wall marker, approach (0.3 m/s peak, as in the sim-vehicle test), hover at 1.5 m; then
    the pilot flips the switch off with the roll stick at 1550 us. In STABILIZE mid throttle is
    ArduCopter's hover throttle and the vertical PID adds thrust, with the same gains. Both modes
    hover within a few cm (bounds 8 cm mean, 5 cm std per axis); every RC_CHANNELS while engaged
    carries one of our overrides; the vehicle flies the pilot's sticks within tens of ms of the
    switch packet; the pilot's mode holds throughout each flight."""
    mission = DartMissionConfig(hover_s=5.0, max_speed_m_s=0.3)
    duration = mission.hover_s + mission.approach_duration_s + 12.0
    results = await fly_dart_arducopter_modes(
        ardupilot_root,
        tmp_path,
        DartParams(mission=mission),
        tuple(MODES),
        duration_s=duration,
        release_after_s=duration - 3.0,
        seed=1,
        pilot_roll_us=1550,
    )
    assert len(results) == len(MODES)
    for (mode, mode_number), r in zip(MODES.items(), results, strict=True):
        s = r.summary.stats
        phases = [ph for _, ph in r.summary.transitions]
        assert phases[:3] == [DartPhase.HOVER_START, DartPhase.APPROACH, DartPhase.HOVER_END], (mode, phases)
        end = r.truth_in(DartPhase.HOVER_END, after_s=3.0)
        assert len(end) >= 60, mode
        mean_err = np.abs(end.mean(axis=0) - np.array([0.0, 0.0, 1.5]))
        std = end.std(axis=0, ddof=1)
        print(
            f"ArduCopter Dart ({mode}) hover at 1.5 m: mean error {mean_err.round(3)} m, std {std.round(3)} m; "
            f"release {r.release_latency_s * 1000:.0f} ms; read back {r.overrides_read_back}/{r.rc_samples_engaged}"
        )
        assert np.all(mean_err < 0.08), (mode, mean_err)
        assert np.all(std < 0.05), (mode, std)
        # the cyber-pilot only adds to the sticks: the pilot's mode throughout
        assert r.modes == {mode_number}, (mode, r.modes)
        # the override values ArduCopter applied are the ones we sent
        assert r.rc_samples_engaged > 20 * (duration - 5.0), mode
        assert r.overrides_read_back >= 0.95 * r.rc_samples_engaged, mode
        # the switch hands back at once: the vehicle flies the radio again (RC_CHANNELS at 50 Hz)
        assert 0.0 < r.release_latency_s < 0.3, (mode, r.release_latency_s, r.notes)
        assert r.summary.releases, f"{mode}: the shell recorded no release"
        assert s.send_errors == 0 and s.vision_errors == 0 and s.frames > 20 * duration, (mode, s)
    assert results[-1].landed, results[-1].notes
