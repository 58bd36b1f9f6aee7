"""Requests to ArduPilot: COMMAND_LONGs retried until acknowledged, the telemetry streams
(ArduCopter streams nothing until asked: message intervals are requested on connect, again if
telemetry stops while heartbeats go on, e.g. after an autopilot reboot, and one by one for a
stream arriving at under half its rate, its request or ack lost on a noisy line), parameters by name,
SYSTEM_TIME, and giving the vehicle a signing key (SETUP_SIGNING)."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import time
from collections.abc import Sequence
from typing import Any

from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.ardupilot.link import ArduPilotLink
from companion.autopilot.interface import (
    AutopilotError,
    CommandRejected,
    CommandResult,
)
from companion.autopilot.signing import (
    AP_KEY_LOAD_OFFSET,
    SigningError,
    SigningKey,
    SigningSetup,
    apply_to_mavlink,
    clock_timestamp,
    setup_signing_message,
)

log = logging.getLogger(__name__)

MAV_CMD_REQUEST_MESSAGE = 512
# a refusal's reason may follow its COMMAND_ACK (ArduPilot queues STATUSTEXTs): this long for it
REASON_WAIT_S = 0.2

# message id -> rate requested on connect (ArduCopter streams nothing until asked)
DEFAULT_STREAM_RATES_HZ: dict[int, float] = {
    30: 50.0,  # ATTITUDE
    105: 50.0,  # HIGHRES_IMU
    27: 50.0,  # RAW_IMU (fallback when HIGHRES_IMU is not supported)
    32: 30.0,  # LOCAL_POSITION_NED
    33: 30.0,  # GLOBAL_POSITION_INT
    24: 5.0,  # GPS_RAW_INT
    1: 5.0,  # SYS_STATUS
    245: 5.0,  # EXTENDED_SYS_STATE
    242: 0.5,  # HOME_POSITION
    147: 1.0,  # BATTERY_STATUS
    65: 5.0,  # RC_CHANNELS
}

# a stream arriving at under THIN_STREAM_SHARE of its rate over a STREAM_CHECK_PERIOD_S window is
# asked for again (its request or its ack may have been lost on a noisy line), at most
# MAX_STREAM_REREQUESTS times; only streams that expect MIN_EXPECTED_IN_WINDOW messages a window
THIN_STREAM_SHARE = 0.5
STREAM_CHECK_PERIOD_S = 5.0
MAX_STREAM_REREQUESTS = 3
MIN_EXPECTED_IN_WINDOW = 10
# answers that mean the autopilot will not send a stream: not asked again
STREAM_REFUSALS = frozenset({CommandResult.UNSUPPORTED, CommandResult.DENIED, CommandResult.FAILED})

HIGHRES_IMU_ID, RAW_IMU_ID = 105, 27
ATTITUDE_STREAMS = (30, HIGHRES_IMU_ID, RAW_IMU_ID)  # the streams [runtime] autopilot_attitude_rate_hz sets
POSITION_STREAMS = (32, 33)  # ... and autopilot_position_rate_hz


def configured_stream_rates(attitude_hz: float | None, position_hz: float | None) -> dict[int, float]:
    """DEFAULT_STREAM_RATES_HZ with the attitude / IMU and the position streams at the configured
    rates (None: the default's)."""
    rates = dict(DEFAULT_STREAM_RATES_HZ)
    for ids, hz in ((ATTITUDE_STREAMS, attitude_hz), (POSITION_STREAMS, position_hz)):
        if hz is not None:
            rates.update(dict.fromkeys(ids, float(hz)))
    return rates


TRY_PERIOD_TS = 100_000  # 1 s in signing timestamp units (10 us)


def result_name(result: int) -> str:
    """The MAV_RESULT name without its prefix ("FAILED", "DENIED", ...), as CommandRejected carries it."""
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name.removeprefix("MAV_RESULT_") if entry is not None else f"MAV_RESULT {result}"


def command_name(cmd: int) -> str:
    entry = mavlink.enums["MAV_CMD"].get(cmd)
    return entry.name if entry is not None else f"MAV_CMD {cmd}"


def _command_long(mav: Any, *, ts: int, tc: int, cmd: int, confirmation: int, params: Sequence[float]) -> None:
    mav.command_long_send(ts, tc, cmd, confirmation, *params)


class ArduPilotRequests(ArduPilotLink):
    """Commands with their acks, stream requests, parameters, SYSTEM_TIME and signing keys."""

    async def _command(self, cmd: int, *params: float, what: str = "", retries: int | None = None) -> None:
        """COMMAND_LONG, resent until its COMMAND_ACK arrives. Anything but ACCEPTED raises
        :class:`CommandRejected` with the MAV_RESULT name (with the STATUSTEXT that came with it),
        :data:`NO_ANSWER` when no ack came after the tries (``LOST`` if the link lost messages
        meanwhile), :data:`LINK_DOWN` without a link."""
        name = what or command_name(cmd)
        if self._conn is None or self._loop is None:
            raise CommandRejected(name, CommandResult.LINK_DOWN, "not connected")
        if not self.link_ok:
            raise CommandRejected(name, CommandResult.LINK_DOWN, "link is down")
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        ts, tc = self.target_system or 1, self.target_component
        old = self._acks.pop(cmd, None)
        if old is not None and not old.done():
            old.cancel()
        fut: asyncio.Future[int] = self._loop.create_future()
        self._acks[cmd] = fut
        texts_before, errors_before = self._texts_seen, self.link_errors
        tries = self.command_retries if retries is None else retries
        try:
            for attempt in range(tries):
                self._send(functools.partial(_command_long, ts=ts, tc=tc, cmd=cmd, confirmation=attempt, params=p))
                self.counters.commands_sent += 1
                try:
                    result = await asyncio.wait_for(asyncio.shield(fut), self.command_timeout_s)
                except TimeoutError:
                    continue
                if result == mavlink.MAV_RESULT_IN_PROGRESS:  # keep waiting for the final ack
                    fut = self._loop.create_future()
                    self._acks[cmd] = fut
                    try:
                        result = await asyncio.wait_for(fut, 30.0)
                    except TimeoutError:
                        raise CommandRejected(
                            name, CommandResult.NO_ANSWER, "IN_PROGRESS without a final ack"
                        ) from None
                if result == mavlink.MAV_RESULT_ACCEPTED:
                    return
                # the reason (e.g. "Arm: Need Position Estimate") is a STATUSTEXT ArduPilot queues and
                # sends from its main loop, so it may follow the ack, which goes out at once
                deadline = self._loop.time() + REASON_WAIT_S
                while self._texts_seen == texts_before and self._loop.time() < deadline:
                    await asyncio.sleep(0.01)
                reason = self._last_text if self._texts_seen != texts_before else ""
                raise CommandRejected(name, result_name(result), reason)
            errors = self.link_errors - errors_before
            if errors > 0:  # a lossy link (a noisy serial line): the acks may have been lost, not refused
                raise CommandRejected(
                    name,
                    CommandResult.LOST,
                    f"no COMMAND_ACK after {tries} tries while the link was losing data ({errors} errors)",
                )
            raise CommandRejected(
                name, CommandResult.NO_ANSWER, f"no COMMAND_ACK after {tries} tries{self._signing_hint()}"
            )
        finally:
            if self._acks.get(cmd) is fut:
                del self._acks[cmd]

    def _signing_hint(self) -> str:
        """Why a vehicle may ignore our commands although we hear it: signing."""
        conn = self._conn
        if self.signing is None and self._vehicle_signs:
            return (
                "; the vehicle signs its packets (MAVLink 2 signing) and ignores our unsigned ones: "
                "set signing.enabled with its key"
            )
        if self.signing is not None and conn is not None and conn.mav.signing.badsig_count > 0:
            return (
                f"; the vehicle's signatures fail our key {self.signing.key.fingerprint} "
                f"({conn.mav.signing.badsig_count} packets): it signs with another key and ignores ours"
            )
        return ""

    async def push_signing_key(
        self, key: SigningKey | None, *, initial_timestamp: int | None = None, timeout_s: float = 3.0, tries: int = 3
    ) -> None:
        """Give the vehicle a signing key with SETUP_SIGNING (``key`` None: the all-zero key that
        turns signing off), then sign with it ourselves and wait for a heartbeat its signature
        verifies. ArduPilot does not acknowledge SETUP_SIGNING, refuses it while armed, and once it
        signs drops an unsigned SETUP_SIGNING except on channel 0 (SERIAL0: USB, SITL TCP 5760).
        Raises :class:`SigningError` when the vehicle does not take the key."""
        conn, loop = self._conn, self._loop
        if conn is None or loop is None or self.target_system is None:
            raise SigningError("push_signing_key: not connected to a vehicle")
        if self._armed:
            raise SigningError("push_signing_key: the vehicle is armed (ArduPilot refuses SETUP_SIGNING when armed)")
        ts = clock_timestamp() if initial_timestamp is None else initial_timestamp
        msg = setup_signing_message(conn.mav, self.target_system, self.target_component, key, ts)
        if key is None:
            for _ in range(tries):
                self._send(lambda mav: mav.send(msg))
                await asyncio.sleep(0.1)
            with self._send_lock:
                conn.disable_signing()
            self.signing = None
            log.info("sent SETUP_SIGNING with the zero key: signing off on the vehicle and here")
            return
        old = self.signing
        setup = SigningSetup(
            key,
            old.link_id if old else 1,
            allow_unsigned=old.allow_unsigned if old else False,
            timestamp_file=old.timestamp_file if old else None,
        )
        # one SETUP_SIGNING per try, each with a later timestamp: ArduPilot sets its timestamp to
        # the pushed one + 60 s, so the same message again would turn its clock back and we would
        # drop its packets as replays
        deadline = loop.time() + timeout_s
        for attempt in range(tries):
            if attempt:
                ts = max(ts + TRY_PERIOD_TS, clock_timestamp())
                msg = setup_signing_message(conn.mav, self.target_system, self.target_component, key, ts)
            with self._send_lock:
                conn.mav.send(msg)  # with the link's current signing (none at first)
                # the vehicle starts 60 s past the pushed timestamp; start there too
                apply_to_mavlink(conn.mav, setup, max(clock_timestamp(), ts + AP_KEY_LOAD_OFFSET))
            if attempt == 0:
                self.signing = setup
            seen = self.counters.signed_from_vehicle
            try_end = min(deadline, loop.time() + timeout_s / tries)
            while loop.time() < try_end:
                if self.counters.signed_from_vehicle > seen:
                    log.info("vehicle %d signs with key %s", self.target_system, key.fingerprint)
                    return
                await asyncio.sleep(0.05)
        raise SigningError(
            f"the vehicle did not start signing with key {key.fingerprint} within {timeout_s:.1f} s after "
            f"SETUP_SIGNING ({tries} sent): ArduPilot ignores it while armed, and once signing drops an "
            "unsigned one off channel 0 (SERIAL0/USB; SITL TCP 5760)"
        )

    def _stream_wanted(self, mid: int) -> bool:
        """RAW_IMU is left out once HIGHRES_IMU was accepted: it is only the fallback, and both at
        50 Hz would have the link decode and drop 50 messages a second."""
        return not (mid == RAW_IMU_ID and self._highres_accepted)

    def _streams_to_request(self) -> list[tuple[int, float]]:
        """The streams to ask for, HIGHRES_IMU before RAW_IMU (whether the fallback is wanted
        depends on the answer to the first)."""
        return sorted(self.stream_rates_hz.items(), key=lambda kv: kv[0] == RAW_IMU_ID)

    async def _request_streams(self) -> None:
        async def one(mid: int, hz: float) -> None:
            try:
                await self._command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mid, 1e6 / hz, retries=2)
            except AutopilotError as err:
                log.info("message %d at %.1f Hz not available: %s", mid, hz, err)
                if isinstance(err, CommandRejected) and err.kind in STREAM_REFUSALS:
                    self._streams_refused.add(mid)
            else:
                if mid == HIGHRES_IMU_ID:
                    self._highres_accepted = True

        self._last_stream_request = time.monotonic()
        self.counters.stream_requests += 1
        self._highres_accepted = False
        self._streams_refused = set()
        for mid, hz in self._streams_to_request():  # one at a time: the ack futures are keyed by command
            if self._stream_wanted(mid):
                await one(mid, hz)
        with contextlib.suppress(AutopilotError):
            await self._command(mavlink.MAV_CMD_REQUEST_MESSAGE, 242, retries=1)
        self._stream_rerequests = {}
        self._stream_window = (time.monotonic(), {})  # the thin-stream check starts counting now

    def _rerequest_streams_fire_and_forget(self) -> None:
        for mid, hz in self._streams_to_request():
            if self._stream_wanted(mid):
                self._send_interval(mid, hz)
        self.counters.stream_requests += 1

    def _send_interval(self, mid: int, hz: float) -> None:
        """SET_MESSAGE_INTERVAL for one stream, its ack not waited for (from the reader thread too)."""
        ts, tc = self.target_system or 1, self.target_component
        self._send(
            functools.partial(
                _command_long,
                ts=ts,
                tc=tc,
                cmd=mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                confirmation=0,
                params=(mid, 1e6 / hz, 0, 0, 0, 0, 0),
            )
        )

    def _count_stream(self, m: Any, now: float) -> None:
        """Reader thread: one message of the vehicle's counted for the thin-stream check, which runs
        once a window."""
        window = self._stream_window
        if window is None or m.get_srcSystem() != self.target_system:
            return
        t0, counts = window
        mid = m.get_msgId()
        counts[mid] = counts.get(mid, 0) + 1
        if now - t0 >= self.stream_check_period_s:
            self._stream_window = (now, {})
            self._rerequest_thin_streams(counts, now - t0)

    def _rerequest_thin_streams(self, counts: dict[int, int], window_s: float) -> None:
        """Ask again (fire and forget) for each stream that arrived at under THIN_STREAM_SHARE of
        its rate, unless the autopilot refused it or it was asked MAX_STREAM_REREQUESTS times."""
        if not self.link_ok:
            return
        for mid, hz in self._streams_to_request():
            expected = hz * window_s
            if (
                not self._stream_wanted(mid)
                or mid in self._streams_refused
                or expected < MIN_EXPECTED_IN_WINDOW
                or counts.get(mid, 0) >= THIN_STREAM_SHARE * expected
            ):
                continue
            n = self._stream_rerequests.get(mid, 0)
            if n >= MAX_STREAM_REREQUESTS:
                continue
            self._stream_rerequests[mid] = n + 1
            self.counters.stream_rerequests += 1
            log.info(
                "message %d: %d in %.1f s of %.0f asked for; asking again (%d of %d)",
                mid,
                counts.get(mid, 0),
                window_s,
                expected,
                n + 1,
                MAX_STREAM_REREQUESTS,
            )
            self._send_interval(mid, hz)

    def _check_streams(self, now: float) -> None:
        if (
            self.link_ok
            and now - self._last_hb < 2.0
            and now - self._last_attitude > 3.0
            and now - self._last_stream_request > 5.0
            and self._last_stream_request > -math.inf
            and self.target_system is not None
        ):
            log.warning("heartbeats but no telemetry: requesting the streams again")
            self._last_stream_request = now
            self._rerequest_streams_fire_and_forget()

    async def read_param(self, name: str, timeout_s: float = 0.4, tries: int = 2) -> float | None:
        """One parameter by name (PARAM_REQUEST_READ), None without an answer."""
        if self._loop is None:
            return None
        ts, tc = self.target_system or 1, self.target_component
        for _ in range(tries):
            fut = self._param_waiters.get(name)
            if fut is None or fut.done():
                fut = self._loop.create_future()
                self._param_waiters[name] = fut
            self._send(lambda mav: mav.param_request_read_send(ts, tc, name.encode(), -1))
            try:
                return await asyncio.wait_for(asyncio.shield(fut), timeout_s)
            except TimeoutError:
                continue
            finally:
                if self._param_waiters.get(name) is fut and fut.done():
                    del self._param_waiters[name]
        self._param_waiters.pop(name, None)
        return None

    async def system_time(self, timeout_s: float = 2.0) -> tuple[int, float] | None:
        """A fresh SYSTEM_TIME as ``(time_unix_usec, our wall clock at its arrival)``, requested with
        MAV_CMD_REQUEST_MESSAGE (ArduPilot also streams it); None without one within ``timeout_s``."""
        if self._loop is None or self._conn is None:
            return None
        fut: asyncio.Future[tuple[int, float]] = self._loop.create_future()
        self._system_time_waiters.append(fut)
        ts, tc = self.target_system or 1, self.target_component
        request = functools.partial(
            _command_long, ts=ts, tc=tc, cmd=MAV_CMD_REQUEST_MESSAGE, confirmation=0, params=(2, 0, 0, 0, 0, 0, 0)
        )
        self._send(request)  # its COMMAND_ACK is not waited for: the message itself answers
        try:
            return await asyncio.wait_for(fut, timeout_s)
        except TimeoutError:
            return None
        finally:
            if fut in self._system_time_waiters:
                self._system_time_waiters.remove(fut)

    def _resolve_system_time(self, value: tuple[int, float]) -> None:
        waiters, self._system_time_waiters = self._system_time_waiters, []
        for fut in waiters:
            if not fut.done():
                fut.set_result(value)

    def _resolve_param(self, name: str, value: float) -> None:
        fut = self._param_waiters.get(name)
        if fut is not None and not fut.done():
            fut.set_result(value)

    def _resolve_ack(self, cmd: int, result: int) -> None:
        fut = self._acks.get(cmd)
        if fut is not None and not fut.done():
            fut.set_result(result)
