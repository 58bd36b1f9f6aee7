"""DartHooks: a bench or test times the Dart shell's named stages and reads its rate loops through
the hooks, over real MAVLink (loopback UDP, the ArduPilot backend against the Dart link sim)."""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable
from typing import Any

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.dart.hooks import DART_STAGES, DartHooks
from companion.dart.params import DartFlightParams
from companion.dart.shell import DART_STREAM_RATES_HZ, DartShell
from companion.scheduling import Clock, RateLoop
from companion_sitl.dart_link import DartLinkSim
from companion_sitl.dart_sim import DartParams
from companion_sitl.mavlink.link import free_udp_port


def test_a_stage_name_the_shell_does_not_have_is_refused():
    with pytest.raises(AssertionError):
        DartHooks(stage_timer=lambda stage, fn: fn).timed("guidance", print)


@pytest.mark.flight
async def test_every_stage_is_timed_and_every_rate_loop_built_through_the_hooks(tmp_path):
    calls: Counter[str] = Counter()
    bound: Counter[str] = Counter()
    lock = threading.Lock()  # "detect" runs on the vision thread

    def timer(stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        bound[stage] += 1

        def counted(*args: Any) -> Any:
            with lock:
                calls[stage] += 1
            return fn(*args)

        return counted

    loops: list[RateLoop] = []

    def rate_loop(clock: Clock, rate_hz: float, start_s: float | None = None) -> RateLoop:
        loops.append(RateLoop(clock, rate_hz, start_s))
        return loops[-1]

    p = DartParams()
    port = free_udp_port()
    with DartLinkSim(p, port=port, dialect="ardupilot", seed=1, estimator=p.runtime.estimator) as sim:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{port}", stream_rates_hz=DART_STREAM_RATES_HZ)
        try:
            await ap.connect(timeout_s=10.0)
            shell = DartShell(
                ap,
                sim.camera,
                DartFlightParams(control=p.control, mission=p.mission, runtime=p.runtime),
                output="rc_override",
                camera_model=sim.camera.camera_model,
                layout=p.sim.layout,
                log_path=tmp_path / "dart.csv",
                hooks=DartHooks(stage_timer=timer, rate_loop=rate_loop),
            )
            sim.set_pilot(switch_on=True)
            summary = await shell.run(3.0)
        finally:
            await ap.close()
    s = summary.stats
    assert set(calls) == set(DART_STAGES) - {"attitude"}, calls  # RC overrides: no attitude setpoint sent
    # each stage bound once where the shell binds it; the IMU's two functions (the samples queued,
    # the estimator's update)
    assert bound == {**dict.fromkeys(DART_STAGES, 1), "imu": 2}, bound
    # the counts are the shell's own: the hooks see every call and nothing else
    assert calls["control"] == s.control_steps
    assert calls["rc_override"] == s.overrides_sent + s.releases_sent
    # a frame read as the run ends may be cancelled before the vision thread detects it
    assert s.frames - 1 <= calls["detect"] <= s.frames, (calls["detect"], s.frames)
    assert calls["vision"] == s.detections
    assert sorted(round(1.0 / r.period_s) for r in loops) == [20, 22, 44, 200]
    assert all(r.ticks > 0 for r in loops)
