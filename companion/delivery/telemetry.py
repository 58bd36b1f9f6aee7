"""Glue between the asyncio shell and the Zenoh publisher: builds the publisher from config and
turns the shell's state into telemetry messages. Publishing is a non-blocking hand-off (the
publisher's worker thread encodes and sends), so it never slows the control loop."""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from companion import __version__
from companion.autopilot.interface import TelemetryCache
from companion.autopilot.types import StatusText, TelemetrySample
from companion.config import CompanionConfig, ConfigError, shipped_params_path
from companion.events import MissionEvent, Phase
from companion.telemetry.auth import CommandSettings, GroundCommand
from companion.telemetry.publisher import TelemetryPublisher, TelemetrySettings, call_in_loop
from companion.telemetry.schema import (
    EstimateMessage,
    HealthMessage,
    LandingMessage,
    LogMessage,
    MissionMessage,
    RejectionCount,
    StateMessage,
    TaskHealth,
)
from companion.telemetry.session import SettingsError, ZenohSettings, load_settings

log = logging.getLogger(__name__)


def zenoh_settings_from_config(cfg: CompanionConfig) -> ZenohSettings:
    ref = cfg.telemetry.zenoh_config
    path = Path(ref)
    if not path.is_file():
        try:
            path = shipped_params_path(ref)
        except ConfigError:  # neither: say both, the path first (a typo in a path is the likelier)
            problem = f"{ref!r}: no file {path.resolve()}, and no shipped parameter set of that name"
            raise ConfigError("telemetry.zenoh_config", [problem]) from None
    try:
        return load_settings(path)
    except SettingsError as err:
        raise ConfigError(str(path), [str(err)]) from None


def make_publisher(
    cfg: CompanionConfig,
    on_command: Callable[[GroundCommand], None] | None,
    zenoh_settings: ZenohSettings | None = None,
    session: Any = None,
) -> TelemetryPublisher:
    """The vehicle's publisher; ``session``: an open Zenoh session to publish on (the order desk's,
    which outlives each flight), else one is opened from ``zenoh_settings`` or the config."""
    t = cfg.telemetry
    c = t.commands
    try:
        secret = CommandSettings.read_secret(c.secret_file) if c.enabled and c.secret_file else None
        commands = CommandSettings(
            enabled=c.enabled,
            secret=secret,
            window_s=c.window_s,
            max_nonces=c.max_nonces,
            rate_per_s=c.rate_per_s,
            burst=c.burst,
            max_requests_per_s=c.max_requests_per_s,
        )
    except (OSError, ValueError) as err:
        raise ConfigError("telemetry.commands.secret_file", [str(err)]) from None
    settings = TelemetrySettings(
        vehicle_id=cfg.vehicle_id,
        state_rate_hz=t.state_rate_hz,
        estimate_rate_hz=t.estimate_rate_hz,
        mission_rate_hz=t.mission_rate_hz,
        landing_rate_hz=t.landing_rate_hz,
        health_rate_hz=t.health_rate_hz,
        event_queue_size=t.event_queue_size,
        commands=commands,
    )
    params = {
        "companion_version": __version__,
        "autopilot": cfg.autopilot,
        "mission": cfg.mission.model_dump(mode="json"),
    }
    if session is not None:
        return TelemetryPublisher(settings, session=session, params=params, on_command=on_command)
    return TelemetryPublisher(
        settings, zenoh_settings or zenoh_settings_from_config(cfg), params=params, on_command=on_command
    )


class ShellTelemetry:
    """What the shell publishes each guidance tick (rates are enforced by the publisher)."""

    def __init__(self, publisher: TelemetryPublisher, telemetry: TelemetryCache):
        self.publisher = publisher
        self._tc = telemetry
        self._last_health = -math.inf
        self._cpu_mark: tuple[float, float] | None = None  # (monotonic, process_time) at the last health
        telemetry.add_listener(self._on_sample)

    def _on_sample(self, sample: TelemetrySample) -> None:
        if isinstance(sample, StatusText):
            self.publisher.publish(LogMessage(sample.time_s, sample.severity, sample.text, source="autopilot"))

    def close(self) -> None:
        self._tc.remove_listener(self._on_sample)

    def tick(
        self, now: float, shell: Any, phase: Phase, sector: int, lyapunov: float, events: tuple[MissionEvent, ...]
    ) -> None:
        pub, tc = self.publisher, self._tc
        est = shell.estimate
        if est is not None:
            pub.publish(StateMessage.from_samples(est, tc.global_position, tc.status, tc.gps, now_s=now))
        fusion = getattr(shell, "fusion", None)
        if fusion is not None and fusion.ekf.initialized:
            fe = fusion.estimate()
            c = fusion.counters
            rejected, accepted = c.rejected, c.accepted
            x = fusion.ekf.x
            pub.publish(
                EstimateMessage(
                    fe.time_s,
                    "ekf",
                    fe.north_m,
                    fe.east_m,
                    fe.down_m,
                    fe.roll_rad,
                    fe.pitch_rad,
                    fe.yaw_rad,
                    fe.gps_bias_north_m,
                    fe.gps_bias_east_m,
                    fe.gps_bias_down_m,
                    float(x[9]),
                    float(x[10]),
                    float(x[11]),
                    tuple(float(v) for v in np.diag(fusion.ekf.P)),
                    accepted,
                    rejected,
                )
            )
            detector = getattr(getattr(shell, "landing", None), "detector", None)
            pub.publish(landing_message(now, fusion, detector, towards_pad=phase in TOWARDS_PAD))
        v = None if not math.isfinite(lyapunov) else lyapunov
        mission = shell.mission
        speed_ref = getattr(mission, "speed_ref_m_s", None)
        sense = int(getattr(mission, "sense", 0))
        to_pad = None
        pad = getattr(mission, "pad_ned", None)
        if est is not None and pad is not None:
            to_pad = math.hypot(est.north_m - float(pad[0]), est.east_m - float(pad[1]))
        pub.publish(MissionMessage(now, phase, sector or None, v, speed_ref, sense, to_pad))
        for ev in events:
            pub.publish(MissionMessage(now, phase, sector or None, v, speed_ref, sense, to_pad, event=ev))
        if now - self._last_health >= 1.0:
            self._last_health = now
            st = shell.stats
            rt = shell.config.runtime
            wall, cpu = time.monotonic(), time.process_time()
            cpu_pct = None
            if self._cpu_mark is not None and wall > self._cpu_mark[0]:
                cpu_pct = 100.0 * (cpu - self._cpu_mark[1]) / (wall - self._cpu_mark[0])
            self._cpu_mark = (wall, cpu)
            pub.publish(
                HealthMessage(
                    now,
                    link_ok=shell.autopilot.link_ok,
                    heartbeat_age_s=shell.autopilot.heartbeat_age_s,
                    cpu_pct=cpu_pct,
                    tasks=(
                        TaskHealth("guidance", rt.guidance_rate_hz, st.guidance_overruns),
                        TaskHealth("setpoint_stream", rt.setpoint_rate_hz, st.setpoint_overruns),
                    ),
                    rejected=tuple(RejectionCount(k, n) for k, n in sorted(tc.rejected.items()))
                    + tuple(RejectionCount(k, n) for k, n in sorted(pub.refusal_counts().items()) if n),
                    telemetry_dropped=pub.counters().dropped,
                )
            )


#: A pad observation / UWB fix fused more recently than this counts as current.
FRESH_S = 0.5


def _age(age_s: float) -> float | None:
    return max(0.0, age_s) if math.isfinite(age_s) else None


#: The phases in which the pad is where the vehicle is going (or standing): the landing error
#: is published in these only (on the way home the distance to the pad is no landing error).
TOWARDS_PAD = (
    Phase.OUTBOUND,
    Phase.LANDING_PAD,
    Phase.RELEASE,
    Phase.PAD_HOLD,
    Phase.PAD_SEARCH,
    Phase.DIVERT,
    Phase.WINCH,
    Phase.DROP_ZONE_HOLD,
)


def landing_message(now: float, fusion: Any, detector: Any = None, towards_pad: bool = True) -> LandingMessage:
    """The landing topic from the fusion's last accepted pad observation and UWB fix, each with
    its age; fields with no source yet are absent, and so is the landing error when the vehicle
    is not ``towards_pad``."""
    obs_age = _age(fusion.marker_age_s(now))
    uwb_age = _age(fusion.uwb_age_s(now))
    seen = fusion.last_sighting
    fix = fusion.last_uwb_fix
    layout = getattr(detector, "layout", None)
    ids: tuple[int, ...] = ()
    if seen is not None and layout is not None:
        ids = tuple(int(getattr(layout, f"{name}_id")) for name in seen.markers if name in ("outer", "inner"))
    return LandingMessage(
        now,
        pad_visible=obs_age is not None and obs_age < FRESH_S,
        markers_seen=ids,
        marker_names=seen.markers if seen is not None else (),
        pad_rel_north_m=seen.pad_rel_ned_m[0] if seen is not None else None,
        pad_rel_east_m=seen.pad_rel_ned_m[1] if seen is not None else None,
        pad_rel_down_m=seen.pad_rel_ned_m[2] if seen is not None else None,
        observation_age_s=obs_age,
        landing_error_m=fusion.horizontal_error_to_pad_m() if towards_pad else None,
        uwb_fix_ok=uwb_age is not None and uwb_age < FRESH_S,
        uwb_anchors_used=len(fix.anchors_used) if fix is not None else 0,
        uwb_residual_m=float(fix.residual_rms_m) if fix is not None else None,
        uwb_fix_age_s=uwb_age,
    )


def command_handler(loop: asyncio.AbstractEventLoop, shell: Any) -> Callable[[GroundCommand], Any]:
    """Hop a verified ground command from Zenoh's thread onto the shell's loop."""
    return call_in_loop(loop, shell.on_ground_command)
