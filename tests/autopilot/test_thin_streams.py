"""A stream whose SET_MESSAGE_INTERVAL (or its ack) was lost is asked for again once a window
shows it arriving at under half its rate; a refused stream never, a silent one at most
MAX_STREAM_REREQUESTS times. Played against the ArduPilot backend over loopback UDP by a bare
pymavlink peer: it drops the first two requests for ATTITUDE (as a noisy line loses them), refuses
HIGHRES_IMU, and acks LOCAL_POSITION_NED but never sends it."""

from __future__ import annotations

import asyncio
import threading
import time

from pymavlink import mavutil

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.requests import MAX_STREAM_REREQUESTS

mavlink = mavutil.mavlink
ATTITUDE, HIGHRES_IMU, LOCAL_POSITION_NED = 30, 105, 32


class _Peer:
    def __init__(self, port: int):
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", dialect="ardupilotmega", source_system=1, source_component=1
        )
        self.requests: dict[int, int] = {}  # message id -> SET_MESSAGE_INTERVAL received
        self.attitude_hz = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _on_command(self, m) -> None:  # type: ignore[no-untyped-def]
        if m.command != mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            self.conn.mav.command_ack_send(m.command, mavlink.MAV_RESULT_ACCEPTED)
            return
        mid = int(m.param1)
        n = self.requests[mid] = self.requests.get(mid, 0) + 1
        if mid == ATTITUDE and n <= 2:
            return  # lost on the line: no ack, no stream
        result = mavlink.MAV_RESULT_UNSUPPORTED if mid == HIGHRES_IMU else mavlink.MAV_RESULT_ACCEPTED
        self.conn.mav.command_ack_send(m.command, result)
        if mid == ATTITUDE:
            self.attitude_hz = 1e6 / m.param2

    def _run(self) -> None:
        next_hb = next_att = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                next_hb = now + 0.1
                self.conn.mav.heartbeat_send(
                    mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 4, mavlink.MAV_STATE_STANDBY
                )
            if self.attitude_hz and now >= next_att:
                next_att = now + 1.0 / self.attitude_hz
                self.conn.mav.attitude_send(int(now * 1000) % 2**32, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            m = self.conn.recv_match(type="COMMAND_LONG", blocking=True, timeout=0.005)
            if m is not None:
                self._on_command(m)

    def __enter__(self) -> _Peer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.conn.close()


async def test_a_lost_stream_request_is_asked_again_and_the_stream_flows(mav, udp_port):
    ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}", command_timeout_s=0.2, command_retries=3)
    ap.stream_check_period_s = 1.0
    with _Peer(udp_port) as peer:
        await ap.connect(timeout_s=10.0)
        assert peer.requests[ATTITUDE] == 2 and peer.attitude_hz == 0.0  # both tries of the connect lost
        await mav.wait_for(lambda: peer.attitude_hz > 0, 10.0, "ATTITUDE asked for again")
        n0 = ap.telemetry.received.get("Attitude", 0)
        await mav.wait_for(lambda: ap.telemetry.received.get("Attitude", 0) - n0 > 20, 10.0, "attitude")
        # the silent stream is asked for a bounded number of times, the refused one never again
        await mav.wait_for(
            lambda: peer.requests.get(LOCAL_POSITION_NED, 0) >= 1 + MAX_STREAM_REREQUESTS, 20.0, "re-requests"
        )
        await asyncio.sleep(2.5)  # two more windows
        assert peer.requests[LOCAL_POSITION_NED] == 1 + MAX_STREAM_REREQUESTS
        assert peer.requests[HIGHRES_IMU] == 1  # UNSUPPORTED at the connect: final
        # flowing since its third ask (a loaded machine may thin a window once more: still bounded)
        assert 3 <= peer.requests[ATTITUDE] <= 2 + MAX_STREAM_REREQUESTS
        # every stream asked for at most its connect tries and MAX_STREAM_REREQUESTS more
        assert all(n <= 2 + MAX_STREAM_REREQUESTS for n in peer.requests.values()), peer.requests
        assert ap.counters.stream_rerequests >= MAX_STREAM_REREQUESTS + 1  # the silent one's, ATTITUDE's
        await ap.close()
