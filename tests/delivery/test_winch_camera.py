"""The camera's look before a winch release ([winch.camera], companion.delivery.winch): at the
line's full length the parcel must be seen down on the pad for confirm_s within wait_s, else no
release, reel in, home with it."""

from __future__ import annotations

import random

from companion.autopilot.winch import WinchStatus
from companion.config import WinchCameraConfig, WinchConfig
from companion.delivery.winch import WinchSequence, WinchStep
from companion.vision.parcel_tag import ParcelSighting

CAM = WinchCameraConfig(enabled=True, down_tolerance_m=0.15, confirm_s=0.5, wait_s=4.0, stale_s=0.5)
CFG = WinchConfig(hover_height_m=5.0, slack_m=0.3, settle_s=0.0, payout_timeout_s=20.0, camera=CAM)


def _at_length(seq: WinchSequence) -> float:
    """Settled, paid out and at the line's full length: the look has begun; returns the time."""
    seq.step(0.0, True, WinchStatus(0.0, 0.0, 0.0), True)
    seq.on_result(0.0, True)
    t = 11.0
    tick = seq.step(t, True, WinchStatus(t, 5.3, 0.0), True)
    assert seq.step_now is WinchStep.LOOK and not tick.release
    assert any(s.endswith("looking for it on the pad with the camera") for s in tick.say)
    return t


def _seen(t: float, bottom_m: float) -> ParcelSighting:
    return ParcelSighting(t, (0.0, 0.0, 4.8), bottom_m)


def _run(seq: WinchSequence, t0: float, bottoms: list[float], dt: float = 0.125) -> tuple[float, list[str]]:
    said: list[str] = []
    t = t0
    for b in bottoms:
        t += dt
        said += seq.step(t, True, WinchStatus(t, 5.3, 0.0), True, _seen(t - 0.0625, b)).say
        if seq.step_now is not WinchStep.LOOK:
            break
    return t, said


def test_seen_down_for_confirm_s_releases() -> None:
    seq = WinchSequence(CFG, 1.0)
    t, said = _run(seq, _at_length(seq), [0.02] * 10)
    assert seq.step_now is WinchStep.RELEASE
    assert "the camera sees the parcel on the pad (its bottom +0.02 m from it)" in said
    assert t - 11.0 == 0.625  # 0.5 s of sightings after the first: the fifth tick (times exact in binary)
    assert seq.step(t + 0.1, True, WinchStatus(t, 5.3, 0.0), True).release


def test_one_sighting_off_the_pad_starts_the_run_again() -> None:
    seq = WinchSequence(CFG, 1.0)
    t, _ = _run(seq, _at_length(seq), [0.0, 0.0, 0.0, 0.4, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert seq.step_now is WinchStep.RELEASE
    assert t - 11.0 == 1.125  # the run began again at the fifth sighting: released at the ninth


def test_caught_above_the_pad_is_not_released_and_says_where() -> None:
    seq = WinchSequence(CFG, 1.0)
    t, _ = _run(seq, _at_length(seq), [1.04] * 60)
    assert seq.step_now is WinchStep.REEL and not seq.delivered
    assert seq.failure == (
        "the camera sees the parcel 1.04 m above the pad with the line out 5.30 m (caught or hanging short)"
    )
    assert t - 11.0 == 4.125  # wait_s, then the first tick past it


def test_not_seen_at_all_is_not_released() -> None:
    seq = WinchSequence(CFG, 1.0)
    t = _at_length(seq)
    while seq.step_now is WinchStep.LOOK:
        t += 0.1
        seq.step(t, True, WinchStatus(t, 5.3, 0.0), True, None)
    assert seq.step_now is WinchStep.REEL and not seq.delivered
    assert seq.failure == "the camera did not see the parcel's tag within 4.0 s with the line out 5.30 m"


def test_stale_sightings_do_not_count() -> None:
    seq = WinchSequence(CFG, 1.0)
    t = _at_length(seq)
    old = _seen(10.0, 0.0)  # taken before the look, and never renewed
    while seq.step_now is WinchStep.LOOK:
        t += 0.1
        seq.step(t, True, WinchStatus(t, 5.3, 0.0), True, old)
    assert seq.step_now is WinchStep.REEL and "did not see" in seq.failure


def test_below_the_pad_plane_is_not_taken_for_down() -> None:
    seq = WinchSequence(CFG, 1.0)
    _run(seq, _at_length(seq), [-0.4] * 60)
    assert seq.step_now is WinchStep.REEL
    assert seq.failure.startswith("the camera sees the parcel 0.40 m below the pad's plane")


def test_without_the_camera_the_line_alone_decides() -> None:
    seq = WinchSequence(CFG.model_copy(update={"camera": WinchCameraConfig()}), 1.0)
    seq.step(0.0, True, WinchStatus(0.0, 0.0, 0.0), True)
    seq.on_result(0.0, True)
    seq.step(11.0, True, WinchStatus(11.0, 5.3, 0.0), True, _seen(10.9, 2.0))
    assert seq.step_now is WinchStep.RELEASE  # a sighting is not even looked at


def test_drawn_sightings_release_only_after_a_whole_run_on_the_pad() -> None:
    # the property: whatever the sightings, a release follows confirm_s of sightings every one of
    # which was within down_tolerance_m, and no release follows any other history
    rng = random.Random(58)
    for _ in range(300):
        seq = WinchSequence(CFG, 1.0)
        t0 = _at_length(seq)
        bottoms = [rng.choice([0.0, 0.1, 0.14, 0.16, 0.5, -0.2]) for _ in range(45)]
        t, _ = _run(seq, t0, bottoms)
        k = round((t - t0) / 0.125)  # sightings given
        on = [abs(b) <= 0.15 for b in bottoms[:k]]
        run = 0
        for ok in reversed(on):
            if not ok:
                break
            run += 1
        if seq.step_now is WinchStep.RELEASE:
            assert run == 5 and not any(all(on[i : i + 5]) for i in range(len(on) - 5)), bottoms[:k]
        else:
            assert seq.step_now is WinchStep.REEL and k == 33  # past wait_s = 4 s
            assert not any(all(on[i : i + 5]) for i in range(len(on) - 4))
