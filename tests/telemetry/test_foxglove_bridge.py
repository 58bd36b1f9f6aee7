"""`companion ground --foxglove`: telemetry received over loopback Zenoh, re-served over the
Foxglove WebSocket protocol, read back by a plain WebSocket client (``foxglove.websocket.v1``)."""

from __future__ import annotations

import json
import struct
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
from websockets.sync.client import ClientConnection, connect

from companion.telemetry.foxglove_bridge import FoxgloveBridge, telemetry_schema
from companion.telemetry.ground import GroundStation
from companion.telemetry.publisher import TelemetryPublisher, TelemetrySettings
from companion.telemetry.schema import StateMessage, Topic
from companion.telemetry.session import ZenohSettings

from .conftest import wait_until

# foxglove-sdk 0.30 answers only "foxglove.sdk.v1" (a handshake offering only
# "foxglove.websocket.v1" gets HTTP 400); the Foxglove app offers both, so does this client.
SUBPROTOCOLS = ["foxglove.websocket.v1", "foxglove.sdk.v1"]
MESSAGE_DATA_OPCODE = 0x01


def state(t: float, north: float) -> StateMessage:
    return StateMessage(
        t, north, 2.0, -10.0, 3.0, 4.0, 0.0, 0.0, 0.0, 0.1, lat_deg=47.39, lon_deg=8.54, battery_pct=88.0
    )


@pytest.fixture
def bridge() -> Iterator[FoxgloveBridge]:
    b = FoxgloveBridge(port=0).start()  # any free port
    yield b
    b.stop()


@pytest.fixture
def fleet(ground_settings: ZenohSettings, vehicle_settings: ZenohSettings, bridge: FoxgloveBridge) -> Iterator[None]:
    """A ground station feeding the bridge and one vehicle ("v1") publishing its state at 50 Hz
    (north_m counts up) until the test ends."""
    station = GroundStation(ground_settings, listener=bridge.on_envelope).start()
    stop = threading.Event()
    pub = TelemetryPublisher(TelemetrySettings("v1", state_rate_hz=100.0), vehicle_settings).start()

    def publish() -> None:
        i = 0
        while not stop.is_set():
            pub.publish(state(float(i), north=float(i)))
            i += 1
            time.sleep(0.02)

    th = threading.Thread(target=publish, daemon=True)
    th.start()
    try:
        assert wait_until(lambda: "v1" in station.snapshot() and station.snapshot()["v1"].received > 0, 5.0)
        yield
    finally:
        stop.set()
        th.join(2.0)
        pub.stop()
        station.stop()


def _recv_until(ws: ClientConnection, want: Any, timeout_s: float = 5.0) -> Any:
    """Messages until ``want(msg)`` returns something (text frames as parsed JSON)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        raw = ws.recv(timeout=max(0.01, end - time.monotonic()))
        msg = json.loads(raw) if isinstance(raw, str) else raw
        got = want(msg)
        if got is not None:
            return got
    raise AssertionError("timed out waiting for the expected Foxglove message")


def test_foxglove_client_subscribes_and_decodes_live_telemetry(fleet: None, bridge: FoxgloveBridge) -> None:
    uri = f"ws://127.0.0.1:{bridge.port}"
    with connect(uri, subprotocols=SUBPROTOCOLS, open_timeout=5.0) as ws:  # type: ignore[arg-type]
        assert ws.subprotocol in SUBPROTOCOLS
        info = _recv_until(ws, lambda m: m if isinstance(m, dict) and m.get("op") == "serverInfo" else None)
        assert info["name"] == "companion ground"
        channels: dict[str, dict[str, Any]] = {}

        def advertised(m: Any) -> Any:
            if isinstance(m, dict) and m.get("op") == "advertise":
                channels.update({c["topic"]: c for c in m["channels"]})
            return channels if {"/v1/state", "/v1/pose", "/v1/location"} <= channels.keys() else None

        _recv_until(ws, advertised)
        st, pose = channels["/v1/state"], channels["/v1/pose"]
        assert st["encoding"] == "json" and st["schemaName"] == "companion.telemetry.state"
        assert st["schemaEncoding"] == "jsonschema" and json.loads(st["schema"]) == telemetry_schema(Topic.STATE)
        assert pose["schemaName"] == "foxglove.PoseInFrame" and channels["/v1/location"]["schemaName"] == (
            "foxglove.LocationFix"
        )
        ws.send(
            json.dumps(
                {
                    "op": "subscribe",
                    "subscriptions": [{"id": 7, "channelId": st["id"]}, {"id": 8, "channelId": pose["id"]}],
                }
            )
        )
        got: dict[int, tuple[int, dict[str, Any]]] = {}

        def data(m: Any) -> Any:
            if isinstance(m, bytes) and m[0] == MESSAGE_DATA_OPCODE:
                sub_id, log_time_ns = struct.unpack_from("<IQ", m, 1)
                got[sub_id] = (log_time_ns, json.loads(m[13:]))
            return got if {7, 8} <= got.keys() else None

        _recv_until(ws, data)
    t_ns, msg = got[7]
    assert abs(t_ns / 1e9 - time.time()) < 60.0  # the ground's receive time, Unix ns
    assert msg["east_m"] == 2.0 and msg["down_m"] == -10.0 and msg["battery_pct"] == 88.0
    assert msg["north_m"] == float(int(msg["north_m"])) >= 0.0 and msg["lat_deg"] == 47.39
    assert isinstance(msg["seq"], int) and msg["mode"] == "unknown"
    _, p = got[8]
    assert p["frame_id"] == "ned" and p["pose"]["position"]["y"] == 2.0 and p["pose"]["position"]["z"] == -10.0
    q = p["pose"]["orientation"]
    assert q["w"] == pytest.approx(0.99875, abs=1e-4) and q["z"] == pytest.approx(0.049979, abs=1e-5)  # yaw 0.1 rad
    assert bridge.forwarded > 0 and bridge.failures == 0


def test_port_out_of_range_is_refused() -> None:
    with pytest.raises(ValueError, match="70000"):
        FoxgloveBridge(port=70000)


def test_cli_ground_rejects_a_bad_foxglove_port(capsys: pytest.CaptureFixture[str]) -> None:
    from companion.cli.main import main

    assert main(["ground", "--foxglove", "--foxglove-port", "-1", "--duration", "0.1", "--no-multicast"]) == 2
    assert "--foxglove-port -1: expected 0..65535" in capsys.readouterr().err
