"""The live fleet in Foxglove: what the ground station receives over Zenoh, re-served over the
Foxglove WebSocket protocol (``foxglove.websocket.v1``) by foxglove-sdk's server.

``companion ground --foxglove [--foxglove-port N]`` starts it; in Foxglove, *Open connection*
-> *Foxglove WebSocket* -> ``ws://HOST:N`` (default port 8765).

Channels, created when a vehicle's first message of a kind arrives (JSON encoding):

=========================  ================================  ====================================
``/<vehicle>/<topic>``     ``companion.telemetry.<topic>``    the telemetry message as sent (its
                                                              fields, plus ``seq``, ``sent_unix_s``)
``/<vehicle>/pose``        ``foxglove.PoseInFrame``           the state's pose, frame ``ned``
``/<vehicle>/location``    ``foxglove.LocationFix``           latitude / longitude (Map panel),
                                                              when the state carries them
``/tf``                    ``foxglove.FrameTransform``        ``world`` (ENU, z up) -> ``ned``
=========================  ================================  ====================================

Log times are the ground's receive times (Unix nanoseconds).
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import threading
import types
import typing
from typing import Any

from companion.foxglove_schemas import (
    ENU_FROM_NED_QUAT,
    FOXGLOVE_SCHEMAS,
    foxglove_time,
    quat_from_euler_zyx,
    time_ns,
)
from companion.telemetry.schema import MESSAGE_TYPES, Envelope, StateMessage, Topic, message_to_dict

log = logging.getLogger(__name__)

DEFAULT_PORT = 8765


def _json_type(tp: Any) -> dict[str, Any]:
    """A JSON-schema fragment for one dataclass field type."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        inner = _json_type(args[0]) if len(args) == 1 else {}
        t = inner.get("type")
        if isinstance(t, str) and len(typing.get_args(tp)) != len(args):
            inner = {**inner, "type": [t, "null"]}
        return inner
    if tp is bool:
        return {"type": "boolean"}
    if tp is int:
        return {"type": "integer"}
    if tp is float:
        return {"type": "number"}
    if tp is str:
        return {"type": "string"}
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return {"type": "string", "enum": [m.value for m in tp]}
    if origin is tuple:
        return {"type": "array"}
    if dataclasses.is_dataclass(tp):
        return {"type": "object"}
    return {}


def telemetry_schema(topic: Topic) -> dict[str, Any]:
    """The JSON schema of one telemetry topic's messages, from its dataclass."""
    cls = MESSAGE_TYPES[topic]
    hints = typing.get_type_hints(cls)
    props = {f.name: _json_type(hints[f.name]) for f in dataclasses.fields(cls)}
    props["seq"] = {"type": "integer"}
    props["sent_unix_s"] = {"type": "number"}
    return {"title": f"companion.telemetry.{topic.value}", "type": "object", "properties": props}


_LOCATION_FIX_SCHEMA = FOXGLOVE_SCHEMAS["foxglove.LocationFix"]


class FoxgloveBridge:
    """A Foxglove WebSocket server fed by a :class:`~companion.telemetry.ground.GroundStation`
    (pass :meth:`on_envelope` as its ``listener``). Thread-safe: Zenoh calls it on its threads."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, name: str = "companion ground"):
        if not (0 <= int(port) <= 65535):
            raise ValueError(f"Foxglove WebSocket port {port!r}: expected 0..65535 (0: any free port)")
        self.host = host
        self.requested_port = int(port)
        self.name = name
        self._lock = threading.Lock()
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[str, Any] = {}
        self.forwarded = 0
        self.failures = 0

    def start(self) -> FoxgloveBridge:
        import foxglove

        if self._server is not None:
            return self
        self._context = foxglove.Context()
        self._server = foxglove.start_server(
            name=self.name, host=self.host, port=self.requested_port, context=self._context
        )
        tf = self._channel("/tf", "foxglove.FrameTransform", FOXGLOVE_SCHEMAS["foxglove.FrameTransform"])
        tf.log(
            {
                "timestamp": foxglove_time(0.0),
                "parent_frame_id": "world",
                "child_frame_id": "ned",
                "translation": {"x": 0.0, "y": 0.0, "z": 0.0},
                "rotation": ENU_FROM_NED_QUAT,
            }
        )
        log.info("Foxglove WebSocket server on ws://%s:%d", self.host, self.port)
        return self

    @property
    def port(self) -> int:
        if self._server is None:
            raise RuntimeError("Foxglove bridge not started")
        return int(self._server.port)

    def stop(self) -> None:
        if self._server is None:
            return
        self._server.stop()
        self._server = None
        with self._lock:
            for ch in self._channels.values():
                ch.close()
            self._channels.clear()

    def __enter__(self) -> FoxgloveBridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _channel(self, topic: str, schema_name: str, schema: dict[str, Any]) -> Any:
        import foxglove

        with self._lock:
            ch = self._channels.get(topic)
            if ch is None:
                ch = foxglove.Channel(
                    topic,
                    schema=foxglove.Schema(name=schema_name, encoding="jsonschema", data=_json_bytes(schema)),
                    message_encoding="json",
                    context=self._context,
                )
                self._channels[topic] = ch
            return ch

    def on_envelope(self, env: Envelope, rx_unix_s: float) -> None:
        """GroundStation listener: forward one received message."""
        if self._server is None:
            return
        try:
            self._forward(env, rx_unix_s)
        except Exception:
            self.failures += 1
            if self.failures in (1, 10, 100, 1000):
                log.exception("Foxglove bridge: forwarding %s/%s failed", env.vehicle_id, env.topic.value)

    def _forward(self, env: Envelope, rx_unix_s: float) -> None:
        vid = env.vehicle_id
        ns = time_ns(rx_unix_s)
        doc = message_to_dict(env.msg)
        doc["seq"] = env.seq
        doc["sent_unix_s"] = env.sent_unix_s
        topic = env.topic.value
        ch = self._channel(f"/{vid}/{topic}", f"companion.telemetry.{topic}", telemetry_schema(env.topic))
        ch.log(doc, log_time=ns)
        self.forwarded += 1
        msg = env.msg
        if isinstance(msg, StateMessage):
            stamp = foxglove_time(rx_unix_s)
            pose = self._channel(f"/{vid}/pose", "foxglove.PoseInFrame", FOXGLOVE_SCHEMAS["foxglove.PoseInFrame"])
            pose.log(
                {
                    "timestamp": stamp,
                    "frame_id": "ned",
                    "pose": {
                        "position": {"x": msg.north_m, "y": msg.east_m, "z": msg.down_m},
                        "orientation": quat_from_euler_zyx(msg.roll_rad, msg.pitch_rad, msg.yaw_rad),
                    },
                },
                log_time=ns,
            )
            if msg.lat_deg is not None and msg.lon_deg is not None:
                fix = self._channel(f"/{vid}/location", "foxglove.LocationFix", _LOCATION_FIX_SCHEMA)
                fix.log(
                    {
                        "timestamp": stamp,
                        "frame_id": "ned",
                        "latitude": msg.lat_deg,
                        "longitude": msg.lon_deg,
                        "altitude": msg.alt_amsl_m if msg.alt_amsl_m is not None else 0.0,
                        "position_covariance": [0.0] * 9,
                        "position_covariance_type": 0,
                    },
                    log_time=ns,
                )


def _json_bytes(schema: dict[str, Any]) -> bytes:
    import json

    return json.dumps(schema, separators=(",", ":")).encode()
