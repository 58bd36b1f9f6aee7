"""The whole pre-flight check: :func:`run_checks` judges the values read, :func:`preflight` reads
them from a connected autopilot (measuring its telemetry rates meanwhile) and judges them."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Mapping
from typing import Any

from companion.autopilot.preflight.ardupilot import check_ardupilot
from companion.autopilot.preflight.link import LinkProbe, check_link_budget
from companion.autopilot.preflight.px4 import check_px4
from companion.autopilot.preflight.readers import probe_clock, read_params, stream_rate_hz
from companion.autopilot.preflight.report import (
    CameraProbe,
    ClockProbe,
    ParamValue,
    PreflightReport,
    RealtimeProbe,
    Requirements,
    StreamProbe,
    UwbProbe,
)
from companion.autopilot.preflight.sensors import (
    STREAMS,
    check_camera,
    check_clock,
    check_realtime,
    check_streams,
    check_uwb,
    clock_verdict,
)


def run_checks(
    req: Requirements,
    params: Mapping[str, ParamValue],
    *,
    camera: CameraProbe | None = None,
    uwb: UwbProbe | None = None,
    clock: ClockProbe | None = None,
    streams: StreamProbe | None = None,
    realtime: RealtimeProbe | None = None,
    link: LinkProbe | None = None,
) -> PreflightReport:
    rows = check_px4(req, params) if req.autopilot == "px4" else check_ardupilot(req, params)
    if streams is not None:
        rows += check_streams(req, streams)
    rows += check_link_budget(req, link)
    rows += check_camera(req, camera)
    rows += check_uwb(req, uwb)
    rows.append(check_clock(req, clock))
    rows += check_realtime(realtime)
    offset = clock.offset_s if clock is not None else None
    return PreflightReport(req.autopilot, tuple(rows), clock_verdict(req, clock), offset)


async def preflight(
    autopilot: Any,
    req: Requirements,
    *,
    camera: CameraProbe | None = None,
    uwb: UwbProbe | None = None,
    stream_window_s: float = 1.5,
    realtime: RealtimeProbe | None = None,
) -> PreflightReport:
    """Read the parameters and the clock from the connected ``autopilot``, measure its position and
    attitude rates and the bytes over its link meanwhile (over ``stream_window_s`` at least), and
    run every check."""
    arrivals: dict[str, list[float]] = {k: [] for k in STREAMS}

    def on_sample(sample: Any) -> None:
        times = arrivals.get(type(sample).__name__)
        if times is not None:
            times.append(time.monotonic())

    tc = autopilot.telemetry
    tc.add_listener(on_sample)
    try:
        t0, traffic0 = time.monotonic(), autopilot.link_traffic()
        params = await read_params(autopilot, req)
        clock = await probe_clock(autopilot)
        rest = stream_window_s - (time.monotonic() - t0)
        if rest > 0:
            await asyncio.sleep(rest)
    finally:
        tc.remove_listener(on_sample)
    seconds, traffic1 = time.monotonic() - t0, autopilot.link_traffic()
    streams = StreamProbe({k: stream_rate_hz(v) for k, v in arrivals.items()}, seconds)

    def rate(b0: int | None, b1: int | None) -> float | None:
        return (b1 - b0) / seconds if b0 is not None and b1 is not None and seconds > 0 else None

    link = LinkProbe(
        traffic1.baud, rate(traffic0.rx_bytes, traffic1.rx_bytes), rate(traffic0.tx_bytes, traffic1.tx_bytes), seconds
    )
    return run_checks(req, params, camera=camera, uwb=uwb, clock=clock, streams=streams, realtime=realtime, link=link)
