"""The Dart cyber-pilot (dart secs. 3-5) on a real ArduCopter SITL: RC_CHANNELS_OVERRIDE added to
the pilot's sticks in ALT_HOLD or STABILIZE, the pilot's switch giving control back, measured at the vehicle.

What is real: ArduCopter 4.7 (its ALT_HOLD and STABILIZE attitude and altitude controllers, its RC input path,
RC_CHANNELS_OVERRIDE handling, its IMU/ATTITUDE/RC_CHANNELS streams), reached through the normal
ArduPilot backend. What is simulated: the pilot's transmitter, sent to the SITL's RC input (UDP
``5501 + 10 x instance``, sixteen little-endian uint16 PWM values, ArduPilot's
AP_RCProtocol_UDP), and the forward camera, which renders the nested wall marker from the SITL's
SIM_STATE ground truth (:class:`TruthWallCamera`, the same renderer as the MAVLink sim vehicle's
:class:`~companion_sitl.dart_link.DartLinkCamera`). The wall marker is placed in front of where
the vehicle hovers when the pilot hands over: ``start_distance_m`` ahead along its true heading.

The release is timed at the vehicle: from the pilot's switch-off packet leaving the transmitter to
the first RC_CHANNELS in which channels 1-4 are the transmitter's sticks again and stay so (the
autopilot flies the radio, no override left). The override values are read back the same way:
each RC_CHANNELS while engaged is compared with the overrides the shell sent just before it.
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import logging
import math
import socket
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.modes import COPTER_MODES
from companion.autopilot.interface import RcInput
from companion.autopilot.types import LandedState
from companion.dart.estimators import wall_marker
from companion.dart.hooks import DartHooks
from companion.dart.mission import DartPhase
from companion.dart.params import DartFlightParams
from companion.dart.shell import DART_STREAM_RATES_HZ, DartRunSummary, DartShell
from companion.geometry import Transform, euler_to_rotmat
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_firmware.truth_feed import MavlinkTruth
from companion_sitl.dart_link import ESTIMATOR_GIMBAL, DartLinkCamera
from companion_sitl.dart_sim import NEUTRAL_US, SWITCH_OFF_US, SWITCH_ON_US, DartParams
from companion_sitl.mavlink.link import free_udp_port

log = logging.getLogger(__name__)

RCIN_PORT = 5501  # ArduPilot SITL's RC input (SIM rcin_port), + 10 per instance
#: ArduCopter parameters for the flight: channel 7 (the cyber-pilot switch) has no function of its
#: own (copter.parm gives it RC7_OPTION = 7, save waypoint); RC_OVERRIDE_TIME is the default 3 s
DART_ARDUCOPTER_PARAMS: dict[str, float] = {"RC7_OPTION": 0.0, "RC_OVERRIDE_TIME": 3.0}
#: the SITL's own RC defaults on channels 5 and 8 (AP_RCProtocol_UDP): kept, so no mode switch moves
SITL_DEFAULT_CH5_CH8_US = 1800


class SitlRcInput:
    """The pilot's transmitter for an ArduPilot SITL: every channel's PWM, sent at ``rate_hz``."""

    def __init__(self, port: int = RCIN_PORT, rate_hz: float = 50.0, channels: int = 16) -> None:
        if channels not in (8, 16):
            raise ValueError(f"channels = {channels}: the SITL reads packets of 8 or 16 values")
        self.addr = ("127.0.0.1", port)
        self.period_s = 1.0 / rate_hz
        self._pwm = [0] * channels  # 0: "ignore this value" (the SITL keeps its own)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = 0
        self.changed_at: dict[int, float] = {}  # channel -> monotonic time of the packet carrying its last change

    def set(self, chans: dict[int, int]) -> float:
        """Set channels (1-based) and send at once; the monotonic time the packet left."""
        with self._lock:
            for ch, us in chans.items():
                if not 1 <= ch <= len(self._pwm):
                    raise ValueError(f"channel {ch}: expected 1..{len(self._pwm)}")
                if not 800 <= us <= 2200:
                    raise ValueError(f"channel {ch} = {us} us: expected 800..2200")
                self._pwm[ch - 1] = int(us)
        t = self._send()
        for ch in chans:
            self.changed_at[ch] = t
        return t

    def value(self, ch: int) -> int:
        with self._lock:
            return self._pwm[ch - 1]

    def _send(self) -> float:
        with self._lock:
            pkt = struct.pack(f"<{len(self._pwm)}H", *self._pwm)
        self._sock.sendto(pkt, self.addr)
        self.sent += 1
        return time.monotonic()

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                self._send()
            except OSError as err:  # the SITL not up yet: its port refuses nothing over UDP, but be safe
                log.debug("rc input: %s", err)

    def start(self) -> SitlRcInput:
        self._thread = threading.Thread(target=self._run, name="sitl-rc-input", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._sock.close()


class TruthWallCamera(DartLinkCamera):
    """The Dart forward camera rendered from an external autopilot's ground truth (SIM_STATE)."""

    def __init__(self, truth: MavlinkTruth, *args: Any, **kwargs: Any) -> None:
        super().__init__(cast(Any, None), *args, **kwargs)
        self.truth = truth

    def _truth(self) -> tuple[Transform, tuple[float, float, float]]:
        t = self.truth
        # rates only matter for the fixed camera's motion blur; the gimballed estimators hold it level
        return Transform(euler_to_rotmat(t.roll, t.pitch, t.yaw), np.array([t.pn, t.pe, t.pd])), (0.0, 0.0, 0.0)


@dataclass
class ArduDartResult:
    summary: DartRunSummary
    truth: list[tuple[float, DartPhase, float, float, float]]  # (time, phase, x, y, z) in the marker frame
    modes: set[int]  # ArduCopter mode numbers seen while the shell ran
    release_latency_s: float  # switch off at the transmitter -> the vehicle flies the radio again
    overrides_read_back: int  # RC_CHANNELS while engaged whose channels 1-4 equal a recent override
    rc_samples_engaged: int
    landed: bool
    notes: list[str] = field(default_factory=list)

    def truth_in(self, phase: DartPhase, after_s: float = 0.0) -> np.ndarray:
        starts = [t for t, ph in self.summary.transitions if ph is phase]
        if not starts:
            return np.zeros((0, 3))
        t0 = starts[-1] + after_s
        return np.array([r[2:] for r in self.truth if r[1] is phase and r[0] >= t0], dtype=float).reshape(-1, 3)


async def _until(cond: Any, timeout_s: float, what: str) -> None:
    t0 = time.monotonic()
    while not cond():
        if time.monotonic() - t0 > timeout_s:
            raise TimeoutError(f"{what}: not within {timeout_s} s")
        await asyncio.sleep(0.05)


def _pilot_channels(p: DartParams, sticks: Sequence[int], switch_us: float) -> dict[int, int]:
    rt = p.runtime
    chans = {5: SITL_DEFAULT_CH5_CH8_US, 8: SITL_DEFAULT_CH5_CH8_US, rt.switch_channel: round(switch_us)}
    for ch, mirror, v in zip(rt.stick_channels, rt.pilot_channels, sticks, strict=True):
        chans[ch] = int(v)
        chans[mirror] = int(v)
    return chans


async def fly_dart_arducopter(
    root: Path,
    log_dir: Path,
    params: DartParams | None = None,
    *,
    duration_s: float,
    release_after_s: float | None = None,
    start_alt_m: float = 2.0,
    seed: int = 0,
    pilot_roll_us: int = 1500,
    mode: str = "ALT_HOLD",
) -> ArduDartResult:
    """Boot ArduCopter, take off in GUIDED to ``start_alt_m``, hand over in ``mode`` with the
    switch on, fly the Dart shell for ``duration_s``; at ``release_after_s`` (shell time) the pilot
    switches it off with the roll stick at ``pilot_roll_us``; then land. ``mode``: the pilot's
    ALT_HOLD (mid throttle holds the height) or STABILIZE (mid throttle is ArduCopter's hover
    throttle; the cyber-pilot's vertical PID adds to it). Needs the SITL build."""
    results = await fly_dart_arducopter_modes(
        root,
        log_dir,
        params,
        (mode,),
        duration_s=duration_s,
        release_after_s=release_after_s,
        start_alt_m=start_alt_m,
        seed=seed,
        pilot_roll_us=pilot_roll_us,
    )
    return results[0]


async def fly_dart_arducopter_modes(
    root: Path,
    log_dir: Path,
    params: DartParams | None,
    modes: Sequence[str],
    *,
    duration_s: float,
    release_after_s: float | None = None,
    start_alt_m: float = 2.0,
    seed: int = 0,
    pilot_roll_us: int = 1500,
) -> list[ArduDartResult]:
    """:func:`fly_dart_arducopter` once per mode in ``modes``, on one boot and one take-off: after
    each flight the pilot has the sticks back (switch off), centres them, selects the next mode and
    switches the cyber-pilot on again, with the wall marker placed ahead of where the vehicle
    hovers then (as the paper's pilot flies to it). The vehicle lands after the last; only the
    last result has ``landed`` set from the landing (the others carry True: it was still flying)."""
    for mode in modes:
        if mode not in ("ALT_HOLD", "STABILIZE"):
            raise ValueError(f"mode {mode!r}: the Dart flies ALT_HOLD or STABILIZE")
    if not modes:
        raise ValueError("modes: at least one")
    p = params or DartParams()
    log_dir.mkdir(parents=True, exist_ok=True)
    truth_port = free_udp_port()
    sitl = ArduCopterSitl(
        root,
        extra_params=dict(DART_ARDUCOPTER_PARAMS),
        serials={1: f"udpclient:127.0.0.1:{truth_port}"},
        log_path=log_dir / "arducopter.log",
    )
    rc = SitlRcInput(port=RCIN_PORT + 10 * sitl.instance)
    sticks = [int(NEUTRAL_US), int(NEUTRAL_US), 1000, int(NEUTRAL_US)]  # throttle low on the ground
    rc.set(_pilot_channels(p, sticks, SWITCH_OFF_US))
    rc.start()
    try:
        with sitl, MavlinkTruth(f"udpin:127.0.0.1:{truth_port}", message="SIM_STATE") as truth:
            await asyncio.to_thread(truth.wait, 15.0)
            ap = ArduPilotAutopilot(sitl.connection, stream_rates_hz=DART_STREAM_RATES_HZ, arm_timeout_s=90.0)
            await ap.connect(timeout_s=20.0)
            try:
                await _take_off(ap, truth, start_alt_m)
                results = []
                for k, mode in enumerate(modes):
                    sticks[:] = [int(NEUTRAL_US), int(NEUTRAL_US), int(NEUTRAL_US), int(NEUTRAL_US)]
                    results.append(
                        await _fly(
                            ap,
                            truth,
                            rc,
                            p,
                            sticks,
                            log_dir / f"{k}-{mode.lower()}" if len(modes) > 1 else log_dir,
                            duration_s,
                            release_after_s,
                            seed + k,
                            pilot_roll_us,
                            [],
                            mode,
                        )
                    )
                results[-1].landed = await _land(ap, results[-1].notes)
                return results
            finally:
                await ap.close()
    finally:
        rc.stop()


def _recording_rc_overrides(sent: list[tuple[float, tuple[int, ...]]]) -> Callable[[str, Callable[..., Any]], Any]:
    """A DartHooks stage timer that appends each RC override the shell hands the backend to
    ``sent`` as (monotonic time, the four stick channels); every other stage is left as it is."""

    def timer(stage: str, send: Callable[..., Any]) -> Callable[..., Any]:
        if stage != "rc_override":
            return send

        def recording_send(channels: Sequence[int]) -> None:
            send(channels)
            sent.append((time.monotonic(), tuple(int(c) for c in list(channels)[:4])))

        return recording_send

    return timer


async def _fly(
    ap: ArduPilotAutopilot,
    truth: MavlinkTruth,
    rc: SitlRcInput,
    p: DartParams,
    sticks: list[int],
    log_dir: Path,
    duration_s: float,
    release_after_s: float | None,
    seed: int,
    pilot_roll_us: int,
    notes: list[str],
    mode: str,
) -> ArduDartResult:
    rt = p.runtime
    log_dir.mkdir(parents=True, exist_ok=True)
    # the pilot's hover: sticks centred, throttle mid (ALT_HOLD holds the height, STABILIZE's mid
    # is the hover throttle), switch off, then the mode
    rc.set(_pilot_channels(p, sticks, SWITCH_OFF_US))
    await asyncio.sleep(0.3)
    await ap.set_mode(mode)
    await _until(lambda: ap.copter_mode == COPTER_MODES[mode], 5.0, mode)
    # the wall marker ahead of the vehicle along its true heading (the paper's pilot has flown there)
    heading = float(truth.yaw)
    R_wm = np.array(wall_marker(heading), dtype=float)
    m = p.mission
    p0 = np.array([truth.pn, truth.pe, truth.pd])
    p_marker = p0 - R_wm @ np.array([m.x_m, m.y_m, m.start_distance_m])
    rt = rt.replaced(marker_heading_deg=math.degrees(heading))
    name = rt.estimator.strip().upper().replace("_", "-")
    camera = TruthWallCamera(
        truth,
        p.sim,
        Transform(R_wm, p_marker),
        gimbal=ESTIMATOR_GIMBAL[name],
        gimbal_heading_rad=heading,
        rate_hz=rt.vision_hz,
        seed=seed,
    )
    sent: list[tuple[float, tuple[int, ...]]] = []  # what the shell sends, for the read-back at the vehicle
    shell = DartShell(
        ap,
        camera,
        DartFlightParams(control=p.control, mission=p.mission, runtime=rt),
        output="rc_override",
        camera_model=camera.camera_model,
        layout=p.sim.layout,
        log_path=log_dir / "dart.csv",
        hooks=DartHooks(stage_timer=_recording_rc_overrides(sent)),
    )
    rc_log: list[tuple[float, tuple[int, ...]]] = []

    def on_rc(r: RcInput) -> None:
        rc_log.append((time.monotonic(), tuple(r.channels_us[:4])))

    ap.telemetry.add_rc_listener(on_rc)
    modes: set[int] = set()
    track: list[tuple[float, DartPhase, float, float, float]] = []
    switch_off_at: list[float] = []

    async def watch() -> None:
        while True:
            modes.add(ap.copter_mode)
            q = R_wm.T @ (np.array([truth.pn, truth.pe, truth.pd]) - p_marker)
            track.append((shell.clock.now(), shell.mission.phase, float(q[0]), float(q[1]), float(q[2])))
            await asyncio.sleep(0.05)

    async def pilot() -> None:
        rc.set(_pilot_channels(p, sticks, SWITCH_ON_US))
        if release_after_s is None:
            return
        await asyncio.sleep(release_after_s)
        sticks[0] = pilot_roll_us
        switch_off_at.append(rc.set(_pilot_channels(p, sticks, SWITCH_OFF_US)))

    loop = asyncio.get_running_loop()
    side = [loop.create_task(watch()), loop.create_task(pilot())]
    try:
        summary = await shell.run(duration_s)
    finally:
        for task in side:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        ap.telemetry.remove_rc_listener(on_rc)
    for task in side:
        if not task.cancelled() and task.exception() is not None:
            raise cast(BaseException, task.exception())
    # read-back: RC_CHANNELS while the switch was on, against the overrides sent in the 0.5 s before
    t_off = switch_off_at[0] if switch_off_at else math.inf
    times = [s[0] for s in sent]
    engaged = [(t, v) for t, v in rc_log if t < t_off and times and times[0] <= t]

    def recent(t: float) -> list[tuple[int, ...]]:
        return [s[1] for s in sent[bisect.bisect_left(times, t - 0.5) : bisect.bisect_right(times, t)]]

    matched = sum(1 for t, v in engaged if v in recent(t))
    latency = math.nan
    if switch_off_at:
        radio = tuple(sticks)
        for i, (t, v) in enumerate(rc_log):
            if t < t_off or v != radio:
                continue
            if all(w == radio for tt, w in rc_log[i:] if tt <= t + 0.5):
                latency = t - t_off
                break
        if not math.isfinite(latency):
            notes.append("the vehicle never flew the radio's sticks after the switch went off")
    return ArduDartResult(summary, track, modes, latency, matched, len(engaged), True, notes)


async def _take_off(ap: ArduPilotAutopilot, truth: MavlinkTruth, start_alt_m: float) -> None:
    await ap.arm()  # GUIDED; refused until EKF3 uses GPS (~40 s), retried by the backend
    await ap.takeoff(start_alt_m)
    await _until(
        lambda: -truth.pd > start_alt_m - 0.2,  # (the Dart streams leave GLOBAL_POSITION_INT out)
        30.0,
        f"take off to {start_alt_m} m",
    )
    await asyncio.sleep(2.0)  # settle


async def _land(ap: ArduPilotAutopilot, notes: list[str]) -> bool:
    """The pilot lands it."""
    await ap.land()
    try:
        await _until(
            lambda: (st := ap.telemetry.status) is not None and st.landed is LandedState.ON_GROUND, 40.0, "landed"
        )
    except TimeoutError as err:
        notes.append(str(err))
        return False
    return True


__all__ = [
    "DART_ARDUCOPTER_PARAMS",
    "RCIN_PORT",
    "ArduDartResult",
    "SitlRcInput",
    "TruthWallCamera",
    "fly_dart_arducopter",
    "fly_dart_arducopter_modes",
]
