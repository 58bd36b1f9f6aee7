"""The pre-flight readers: the thin I/O that fetches what the rules judge, from a connected
backend (PX4: MAVSDK's Param plugin; ArduPilot: PARAM_REQUEST_READ; SYSTEM_TIME on both) and from
the landing camera and UWB drivers."""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import Any

from companion.autopilot.preflight.ardupilot import ardupilot_param_names
from companion.autopilot.preflight.px4 import px4_param_types
from companion.autopilot.preflight.report import (
    CameraProbe,
    ClockProbe,
    ParamUnavailable,
    ParamValue,
    Requirements,
    UwbProbe,
)

log = logging.getLogger(__name__)


async def read_params(autopilot: Any, req: Requirements) -> dict[str, ParamValue]:
    """The parameters the checks need, from a connected PX4 or ArduPilot backend."""
    if req.autopilot == "px4":
        return dict(await autopilot.read_params(px4_param_types(req)))
    out: dict[str, ParamValue] = {}
    for name in ardupilot_param_names(req):
        v = await autopilot.read_param(name)
        out[name] = ParamUnavailable("no PARAM_VALUE answer") if v is None else float(v)
    return out


def clock_probe_from(system_time: tuple[int, float] | None, what: str = "SYSTEM_TIME") -> ClockProbe:
    """A :class:`ClockProbe` from ``(time_unix_usec, companion wall time at arrival)``."""
    if system_time is None:
        return ClockProbe(error=f"no {what} from the autopilot")
    usec, wall = system_time
    if usec <= 0:
        return ClockProbe(error="the autopilot has no UTC time (SYSTEM_TIME.time_unix_usec = 0: no GPS time yet?)")
    return ClockProbe(offset_s=usec / 1e6 - wall)


async def probe_clock(autopilot: Any, timeout_s: float = 2.0) -> ClockProbe:
    try:
        st = await autopilot.system_time(timeout_s)
    except Exception as err:  # a backend error is an unknown row, not a crash
        return ClockProbe(error=f"{type(err).__name__}: {err}")
    return clock_probe_from(st)


def probe_camera(camera: Any, seconds: float = 2.0, started: bool = False, what: str = "") -> CameraProbe:
    """Read a ``companion.cameras`` driver for ``seconds``: frame size and rate (distinct frames
    over the span of their exposure times, so a video file played faster than real time still
    gives its own rate)."""
    times: list[float] = []
    size: tuple[int, int] | None = None
    last_index = None
    t_end = time.monotonic() + seconds
    try:
        if not started:
            camera.start()
        while time.monotonic() < t_end:
            f = camera.read()
            if f is None or f.index == last_index:
                time.sleep(0.002)
                continue
            last_index = f.index
            times.append(float(f.time_s))
            h, w = f.image.shape[:2]
            size = (int(w), int(h))
    except Exception as err:
        return CameraProbe(error=f"{what or 'camera'} ({type(camera).__name__}): {err}")
    finally:
        if not started:
            try:
                camera.stop()
            except Exception as err:
                log.debug("camera stop: %s", err)
    if size is None:
        return CameraProbe(error=f"{what or 'camera'}: no frame within {seconds:g} s")
    fps = stream_rate_hz(times) if len(times) >= 3 else None
    return CameraProbe(size[0], size[1], fps or None, len(times))


def probe_uwb(uwb: Any, seconds: float = 2.0, started: bool = False, what: str = "") -> UwbProbe:
    """Read a ``companion.uwb`` driver for ``seconds``: the anchor ids it reported ranges to."""
    seen: set[str] = set()
    n = 0
    t_end = time.monotonic() + seconds
    try:
        if not started:
            uwb.start()
        while time.monotonic() < t_end:
            r = uwb.read()
            items = r if isinstance(r, list | tuple) else [] if r is None else [r]
            if not items:
                time.sleep(0.01)
                continue
            for item in items:
                n += 1
                seen.update(_anchor_ids(item))
    except Exception as err:
        return UwbProbe(error=f"{what or 'UWB'} ({type(uwb).__name__}): {err}")
    finally:
        if not started:
            try:
                uwb.stop()
            except Exception as err:
                log.debug("uwb stop: %s", err)
    if n == 0:
        return UwbProbe(error=f"{what or 'UWB'}: no reading within {seconds:g} s")
    return UwbProbe(frozenset(seen), n)


def _anchor_ids(reading: Any) -> Sequence[str]:
    ids = getattr(reading, "anchor_ids", None)
    if ids is not None:
        return [str(a) for a in ids]
    anchors = getattr(reading, "anchors", ())
    return [str(getattr(a, "anchor_id", a)) for a in anchors]


def stream_rate_hz(arrivals: Sequence[float]) -> float:
    """Samples per second between the first and the last arrival (a stream that starts late in
    the window is measured while it runs); 0 with fewer than two."""
    if len(arrivals) < 2 or arrivals[-1] <= arrivals[0]:
        return 0.0
    return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])
