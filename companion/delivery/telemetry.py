"""Glue between the asyncio shell and the Zenoh publisher: builds the publisher from config and
turns the shell's state into telemetry messages. Publishing is a non-blocking hand-off (the
publisher's worker thread encodes and sends), so it never slows the control loop."""

from __future__ import annotations

import asyncio
import logging
import math
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
        path = shipped_params_path(ref)
    try:
        return load_settings(path)
    except SettingsError as err:
        raise ConfigError(str(path), [str(err)]) from None


def make_publisher(
    cfg: CompanionConfig,
    on_command: Callable[[GroundCommand], None] | None,
    zenoh_settings: ZenohSettings | None = None,
) -> TelemetryPublisher:
    t = cfg.telemetry
    c = t.commands
    try:
        secret = CommandSettings.read_secret(c.secret_file) if c.enabled and c.secret_file else None
        commands = CommandSettings(enabled=c.enabled, secret=secret, window_s=c.window_s, max_nonces=c.max_nonces)
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
    return TelemetryPublisher(
        settings, zenoh_settings or zenoh_settings_from_config(cfg), params=params, on_command=on_command
    )


class ShellTelemetry:
    """What the shell publishes each guidance tick (rates are enforced by the publisher)."""

    def __init__(self, publisher: TelemetryPublisher, telemetry: TelemetryCache):
        self.publisher = publisher
        self._tc = telemetry
        self._last_health = -math.inf
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
            pub.publish(StateMessage.from_samples(est, tc.global_position, tc.status, tc.gps))
        fusion = getattr(shell, "fusion", None)
        if fusion is not None and fusion.ekf.initialized:
            fe = fusion.estimate()
            c = fusion.counters
            rejected = sum(n for k, n in c.outcomes.items() if ".rejected" in k)
            accepted = sum(n for k, n in c.outcomes.items() if k.endswith(".accepted"))
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
            age = fusion.pad_data_age_s(now)
            pub.publish(
                LandingMessage(
                    now,
                    pad_visible=math.isfinite(age) and age < 0.5,
                    observation_age_s=age if math.isfinite(age) else None,
                    uwb_fix_ok=c.uwb_used > 0,
                )
            )
        v = None if not math.isfinite(lyapunov) else lyapunov
        pub.publish(MissionMessage(now, phase, sector or None, v))
        for ev in events:
            pub.publish(MissionMessage(now, phase, sector or None, v, event=ev))
        if now - self._last_health >= 1.0:
            self._last_health = now
            st = shell.stats
            rt = shell.config.runtime
            pub.publish(
                HealthMessage(
                    now,
                    link_ok=shell.autopilot.link_ok,
                    tasks=(
                        TaskHealth("guidance", rt.guidance_rate_hz, st.guidance_overruns),
                        TaskHealth("setpoint_stream", rt.setpoint_rate_hz, st.setpoint_overruns),
                    ),
                    rejected=tuple(RejectionCount(k, n) for k, n in sorted(tc.rejected.items())),
                    telemetry_dropped=pub.counters().dropped,
                )
            )


def command_handler(loop: asyncio.AbstractEventLoop, shell: Any) -> Callable[[GroundCommand], Any]:
    """Hop a verified ground command from Zenoh's thread onto the shell's loop."""
    return call_in_loop(loop, shell.on_ground_command)
