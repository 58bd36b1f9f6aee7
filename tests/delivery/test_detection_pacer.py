"""The detector paced to a share of one core (runtime.vision_cpu_budget): the rule, on given CPU costs."""

from __future__ import annotations

import math

import pytest

from companion.config import DEFAULT_PARAMS, load_config, shipped_params_path
from companion.delivery.detection_pacer import DetectionPacer


def test_the_next_detection_waits_cost_over_budget():
    p = DetectionPacer(0.05, smoothing=1.0)
    assert p.due(0.0) and p.rate_hz == math.inf
    p.done(0.0, 0.003)  # 3 ms of CPU at 5 % of a core: the next no sooner than 60 ms later
    assert not p.due(0.033) and not p.due(0.0599)
    assert p.due(0.060)
    assert p.skipped == 2 and p.detections == 1
    assert p.rate_hz == pytest.approx(0.05 / 0.003)


def test_the_cost_is_smoothed_so_one_slow_frame_does_not_stall_the_camera():
    p = DetectionPacer(0.1, smoothing=0.25)
    for k in range(10):
        p.done(k * 0.1, 0.002)
    p.done(1.0, 0.050)  # one 50 ms outlier
    assert p.cost_s == pytest.approx(0.002 + 0.25 * 0.048)
    # due 140 ms after it began (the smoothed 14 ms over 10 %), not the 500 ms of the outlier alone
    assert not p.due(1.10)
    assert p.due(1.15)


def test_the_share_holds_over_a_stream_of_frames():
    # 30 fps frames, each detection 4 ms of CPU, budget 6 % of a core: ~15 detections a second
    p = DetectionPacer(0.06)
    cpu = 0.0
    for i in range(300):
        t = i / 30.0
        if p.due(t):
            p.done(t, 0.004)
            cpu += 0.004
    assert cpu / 10.0 <= 0.06 + 1e-9
    assert 140 <= p.detections <= 151


@pytest.mark.parametrize("bad", [0.0, -0.1, math.nan, math.inf])
def test_a_bad_budget_is_refused(bad):
    with pytest.raises(ValueError, match="vision CPU budget"):
        DetectionPacer(bad)


def test_off_by_default():
    cfg = load_config(shipped_params_path(DEFAULT_PARAMS))
    assert cfg.runtime.vision_cpu_budget == 0.0


def test_the_detector_thread_lowers_its_own_priority_once():
    import os
    import threading

    from companion.delivery.detector_thread import cpu_timed

    seen: dict[str, int] = {}

    def on_thread() -> None:
        tid = threading.get_native_id()
        before = os.getpriority(os.PRIO_PROCESS, tid)
        out, cpu_s = cpu_timed(lambda x: x + 1, 1, nice=before + 5)
        seen.update(out=out, before=before, after=os.getpriority(os.PRIO_PROCESS, tid), cpu_ok=int(cpu_s >= 0))

    t = threading.Thread(target=on_thread)
    t.start()
    t.join()
    assert seen["out"] == 2 and seen["cpu_ok"] == 1
    assert seen["after"] == min(19, seen["before"] + 5)
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == seen["before"]  # only that thread


def test_the_detector_thread_runs_one_below_the_loops_real_time_priority():
    import os
    import threading

    from companion.delivery.detector_thread import cpu_timed
    from companion.scheduling import thread_policy

    seen: dict[str, object] = {}

    def on_thread() -> None:
        out, _ = cpu_timed(lambda x: x * 2, 3, nice=10, realtime=12)
        seen.update(out=out, policy=thread_policy())

    t = threading.Thread(target=on_thread)
    t.start()
    t.join()
    pol = seen["policy"]
    assert seen["out"] == 6
    if pol.policy == os.SCHED_OTHER:  # refused here: the warning said why, the thread kept its policy
        pytest.skip("SCHED_RR refused on this machine")
    assert (pol.policy, pol.priority) == (os.SCHED_RR, 11)  # the nice value does not apply
