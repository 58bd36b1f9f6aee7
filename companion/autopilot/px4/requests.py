"""Requests to PX4: MAVSDK calls and COMMAND_LONGs through MavlinkDirect, each bounded by
``command_timeout_s`` and ending in :class:`CommandRejected` with PX4's MAV_RESULT; parameters
through MAVSDK's Param plugin; SYSTEM_TIME."""

from __future__ import annotations

import asyncio
import contextlib
import enum
import json
import logging
import time
from collections.abc import Awaitable, Callable
from typing import Any, Literal

from companion.autopilot.interface import (
    LINK_DOWN,
    NO_ANSWER,
    CommandRejected,
)
from companion.autopilot.px4.telemetry import Px4Telemetry

log = logging.getLogger(__name__)

MAV_CMD_REQUEST_MESSAGE = 512


class MavResult(enum.IntEnum):
    """MAV_RESULT (MAVLink common.xml): how PX4 answered a command. Its name is what
    :attr:`CommandRejected.result` carries."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5
    CANCELLED = 6


MAV_RESULT_NAMES = {r.value: r.name for r in MavResult}
# MAVSDK's Action/Offboard results (the plugins' result enums, by member name: each plugin has its
# own enum) -> the MAV_RESULT behind them, or the outcome without a COMMAND_ACK
_MAVSDK_RESULTS: dict[str, MavResult | str] = {
    "COMMAND_DENIED": MavResult.DENIED,
    "COMMAND_DENIED_LANDED_STATE_UNKNOWN": MavResult.DENIED,
    "COMMAND_DENIED_NOT_LANDED": MavResult.DENIED,
    "UNSUPPORTED": MavResult.UNSUPPORTED,
    "FAILED": MavResult.FAILED,
    "BUSY": MavResult.TEMPORARILY_REJECTED,
    "TIMEOUT": NO_ANSWER,
    "NO_SYSTEM": LINK_DOWN,
    "CONNECTION_ERROR": LINK_DOWN,
}


class Px4CommandRejected(CommandRejected):
    """:class:`CommandRejected` keeping PX4's answer as a type: ``mav_result`` is the MAV_RESULT
    (None: no answer, the link down, or a MAVSDK result with no MAV_RESULT behind it);
    ``result`` its name, as every backend's refusal carries it."""

    def __init__(self, command: str, result: MavResult | str, reason: str = ""):
        super().__init__(command, result.name if isinstance(result, MavResult) else result, reason)
        self.mav_result = result if isinstance(result, MavResult) else None


def _mavsdk_result_name(err: Exception) -> str:
    """The member name of the result a MAVSDK plugin error carries (``ActionError.result``, an
    ``ActionResult``; ``OffboardError.result``, ...); the text before ``;`` where there is none."""
    result = getattr(err, "result", None)
    if isinstance(result, enum.Enum):
        return result.name
    return str(err).split(";", 1)[0].strip()


class Px4Requests(Px4Telemetry):
    """MAVSDK calls and direct commands with their results, parameters and the autopilot's clock."""

    async def read_params(
        self, names: dict[str, Literal["int", "float"]], timeout_s: float = 5.0
    ) -> dict[str, float | Any]:
        """Parameters by name through MAVSDK's Param plugin (PX4 sends int32 parameters byte-wise;
        the plugin decodes them by their type). ``names`` maps each name to its PX4 type; a
        WRONG_TYPE answer is retried as the other type. Each value is a float, or a
        :class:`companion.autopilot.preflight.report.ParamUnavailable` with MAVSDK's reason."""
        from mavsdk.asyncio.plugins.param import ParamAsync
        from mavsdk.plugins.param import ParamError, ParamResult

        from companion.autopilot.preflight.report import ParamUnavailable

        if self._system is None:
            return {n: ParamUnavailable("not connected") for n in names}
        if self._param is None:
            self._param = ParamAsync(self._system)
        param = self._param
        out: dict[str, float | Any] = {}
        for name, kind in names.items():
            getters = [param.get_param_int, param.get_param_float]
            if kind == "float":
                getters.reverse()
            for i, get in enumerate(getters):
                try:
                    out[name] = float(await asyncio.wait_for(get(name), timeout_s))
                except TimeoutError:
                    self.calls_unanswered += 1
                    out[name] = ParamUnavailable(f"no answer within {timeout_s:g} s")
                except ParamError as err:
                    if err.result == ParamResult.WRONG_TYPE and i == 0:
                        continue
                    out[name] = ParamUnavailable(f"MAVSDK {err.result.name}")
                break
        return out

    async def system_time(self, timeout_s: float = 2.0) -> tuple[int, float] | None:
        """A fresh SYSTEM_TIME as ``(time_unix_usec, our wall clock at its arrival)``, requested
        with MAV_CMD_REQUEST_MESSAGE through MavlinkDirect; None without one within ``timeout_s``."""
        if self._system is None:
            return None
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[tuple[int, float]] = loop.create_future()

        def on_time(m: Any) -> None:
            if m.system_id != self.system_id or fut.done():
                return
            try:
                usec = int(json.loads(m.fields_json)["time_unix_usec"])
            except (ValueError, TypeError, KeyError) as err:
                log.warning("SYSTEM_TIME not understood (%s): %s", err, m.fields_json)
                return
            fut.set_result((usec, time.time()))

        task = loop.create_task(self._consume(lambda: self._direct.subscribe_message("SYSTEM_TIME"), on_time))
        try:
            await asyncio.sleep(0.05)  # subscribed before the request goes out
            try:
                await self._direct_command("request SYSTEM_TIME", MAV_CMD_REQUEST_MESSAGE, 2)
            except CommandRejected as err:
                log.info("SYSTEM_TIME request: %s (waiting for the stream)", err)
            return await asyncio.wait_for(fut, timeout_s)
        except TimeoutError:
            return None
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

    # ------------------------------------------------------------------ commands
    async def _call(self, name: str, fn: Callable[[], Awaitable[Any]]) -> Any:
        """One MAVSDK call, bounded by ``command_timeout_s``; failures as :class:`CommandRejected`."""
        if self._system is None:
            raise Px4CommandRejected(name, LINK_DOWN, "not connected")
        if not self.link_ok:
            raise Px4CommandRejected(name, LINK_DOWN, "link is down")
        texts_before = self._texts_seen
        try:
            return await asyncio.wait_for(fn(), self.command_timeout_s)
        except TimeoutError:
            # the native call goes on blocking a MAVSDK thread; we stop waiting for it
            self.calls_unanswered += 1
            raise Px4CommandRejected(name, NO_ANSWER, f"no answer within {self.command_timeout_s:.1f} s") from None
        except Exception as err:  # MAVSDK's ActionError, OffboardError, ... (all MavsdkError)
            await asyncio.sleep(0.05)  # the STATUSTEXT with PX4's reason follows the ack
            reason = self._last_text if self._texts_seen != texts_before else ""
            code = _mavsdk_result_name(err)
            result = _MAVSDK_RESULTS.get(code, code or type(err).__name__)
            raise Px4CommandRejected(name, result, reason or str(err)) from None

    async def _direct_command(self, name: str, command: int, *params: float) -> None:
        """COMMAND_LONG through MavlinkDirect; returns on ACCEPTED, else :class:`CommandRejected`."""
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkMessage

        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        fields: dict[str, float] = {
            "target_system": self.system_id,
            "target_component": 1,
            "command": command,
            "confirmation": 0,
        }
        fields.update({f"param{i + 1}": v for i, v in enumerate(p)})
        msg = MavlinkMessage("COMMAND_LONG", 0, 0, self.system_id, 1, json.dumps(fields))
        texts_before = self._texts_seen
        ack = await self._call(name, lambda: self._direct.send_command(msg))
        result = json.loads(ack.fields_json).get("result", -1) if ack.fields_json else -1
        if result != 0:
            await asyncio.sleep(0.05)  # PX4's STATUSTEXT with the reason follows the ack
            reason = self._last_text if self._texts_seen != texts_before else ""
            known = result in MAV_RESULT_NAMES
            raise Px4CommandRejected(name, MavResult(result) if known else str(result), reason)
