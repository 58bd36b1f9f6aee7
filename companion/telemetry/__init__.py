"""companion.telemetry: ground telemetry over Eclipse Zenoh.

- :mod:`.schema`    key space ``companion/<vehicle_id>/...``, message dataclasses, JSON codec
                    (schema ``companion.telemetry/1``)
- :mod:`.session`   :class:`ZenohSettings` -> ``zenoh.Config`` (peer / client / router)
- :mod:`.publisher` :class:`TelemetryPublisher`: off-the-hot-path publishing, presence, info
- :mod:`.auth`      ground commands: HMAC-SHA256, time window, nonce replay protection
- :mod:`.ground`    :class:`GroundStation`: live fleet table, recording, commands
- :mod:`.bench`     :func:`bench_telemetry`
- :mod:`.commands`  ``companion ground`` and ``companion bench telemetry``
"""

from companion.telemetry.auth import (
    CommandKind,
    CommandRefused,
    CommandSettings,
    CommandVerifier,
    GroundCommand,
    sign_command,
)
from companion.telemetry.publisher import (
    PublisherCounters,
    TelemetryPublisher,
    TelemetrySettings,
    call_in_loop,
)
from companion.telemetry.schema import (
    SCHEMA,
    Envelope,
    EstimateMessage,
    HealthMessage,
    LandingMessage,
    LogMessage,
    Message,
    MissionMessage,
    RejectionCount,
    SchemaError,
    SensorHealth,
    StateMessage,
    TaskHealth,
    Topic,
    decode,
    encode,
)
from companion.telemetry.session import SessionOpenError, SettingsError, ZenohSettings, load_settings

__all__ = [
    "SCHEMA",
    "CommandKind",
    "CommandRefused",
    "CommandSettings",
    "CommandVerifier",
    "Envelope",
    "EstimateMessage",
    "GroundCommand",
    "HealthMessage",
    "LandingMessage",
    "LogMessage",
    "Message",
    "MissionMessage",
    "PublisherCounters",
    "RejectionCount",
    "SchemaError",
    "SensorHealth",
    "SessionOpenError",
    "SettingsError",
    "StateMessage",
    "TaskHealth",
    "TelemetryPublisher",
    "TelemetrySettings",
    "Topic",
    "ZenohSettings",
    "call_in_loop",
    "decode",
    "encode",
    "load_settings",
    "sign_command",
]
