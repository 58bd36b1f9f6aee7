"""A command without its COMMAND_ACK on a link that loses messages is LOST (sent again by the
mission), on a clean link NO_ANSWER (the autopilot ignores it: not sent again). Played against
the ArduPilot backend over loopback UDP by a bare pymavlink peer that never acks and, in the
lossy case, skips sequence numbers as a noisy serial line does (it acks the connect's stream
requests, as ArduCopter does)."""

from __future__ import annotations

import asyncio
import threading

import pytest
from pymavlink import mavutil

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.autopilot import ARM_RETRY_RESULTS
from companion.autopilot.interface import CommandRejected, CommandResult

mavlink = mavutil.mavlink


class _SilentVehicle:
    """Heartbeats at 20 Hz to the companion's port; acks every command but DO_SET_MODE (records
    them); ``skip`` sequence numbers dropped after every fifth message (what lost frames look like)."""

    def __init__(self, port: int, skip: int):
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", dialect="ardupilotmega", source_system=1, source_component=1
        )
        self.skip = skip
        self.commands: list[int] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        n = 0
        while not self._stop.is_set():
            self.conn.mav.heartbeat_send(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 4, mavlink.MAV_STATE_STANDBY
            )
            n += 1
            if self.skip and n % 5 == 0:
                self.conn.mav.seq = (self.conn.mav.seq + self.skip) % 256
            m = self.conn.recv_match(type="COMMAND_LONG", blocking=True, timeout=0.05)
            if m is not None:
                self.commands.append(m.command)
                if m.command != mavlink.MAV_CMD_DO_SET_MODE:
                    self.conn.mav.command_ack_send(m.command, mavlink.MAV_RESULT_ACCEPTED)

    def __enter__(self) -> _SilentVehicle:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.conn.close()


@pytest.mark.parametrize(("skip", "kind"), [(0, CommandResult.NO_ANSWER), (2, CommandResult.LOST)])
async def test_silence_is_lost_on_a_lossy_link_and_no_answer_on_a_clean_one(mav, udp_port, skip, kind):
    ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}", command_timeout_s=0.3, command_retries=3)
    with _SilentVehicle(udp_port, skip) as vehicle:
        await ap.connect(timeout_s=3.0)
        lost0 = ap.link_errors
        with pytest.raises(CommandRejected) as info:
            await ap.land()  # DO_SET_MODE LAND
        lost = ap.link_errors - lost0
        await ap.close()
        await asyncio.sleep(0)
    err = info.value
    assert err.kind is kind
    assert vehicle.commands.count(mavlink.MAV_CMD_DO_SET_MODE) == 3  # every try went out
    if kind is CommandResult.LOST:
        assert lost > 0 and not err.permanent and "while the link was losing data" in str(err)
        assert err.kind in ARM_RETRY_RESULTS  # an arm retries it within its timeout
    else:
        assert lost == 0 and err.permanent
