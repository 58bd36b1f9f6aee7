"""Per-stream flight logs: one CSV per input and output of the core, in the run folder.

:class:`FlightRecorder` is handed to :class:`companion.delivery.shell.DeliveryShell` (``recorder=``). It
listens to the autopilot's :class:`~companion.autopilot.interface.TelemetryCache` and the shell
calls it where pad observations, UWB fixes, request results, operator/ground commands, guidance
ticks and sent setpoints pass. Each stream is a :class:`~companion.flightlog.csvlog.CsvLog`
(batches handed at least every 0.1 s to the logging process, which writes them; time in seconds first, units in the
headers), so PlotJuggler opens every file as is:

=====================  ==========================================================================
``ap_position.csv``    autopilot local position and velocity (LOCAL_POSITION_NED), NED
``ap_attitude.csv``    attitude and body rates
``ap_global.csv``      global position; ``ap_gps.csv`` raw GPS; ``ap_imu.csv`` IMU
``ap_status.csv``      armed, mode, landed state, health, battery, payload
``ap_home.csv``        home position; ``ap_statustext.csv`` autopilot messages
``camera.csv``         pad observations as the fusion receives them (exposure time, T_camera_pad)
``uwb.csv``            UWB fixes in the anchor frame as the fusion receives them
``ekf.csv``            the fused EKF state at each guidance tick: position, attitude, GPS bias,
                       gyro bias, covariance diagonal
``guidance.csv``       each guidance tick: the estimate the mission used, phase, sector, V, the
                       mission's setpoint and the clamped one sent, the request issued
``setpoints.csv``      every setpoint the stream sent to the autopilot
``requests.csv``       results of autopilot requests as fed back to the mission
``commands.csv``       operator aborts (Ctrl-C), ground commands and go/no-go verdicts reached
                       outside a tick (the fence upload) as applied to the mission
``events.csv``         mission events as they happen
``wind.csv``           the autopilot's wind estimate each tick handed the mission (only with the
                       wind go/no-go on, ``go_no_go.wind_limit_m_s`` > 0, or a winch delivery)
``winch.csv``          the winch's report each tick handed the mission (only for a winch delivery)
``drop_zone.csv``      the drop-zone verdict each tick handed the mission (only with
                       ``[landing.drop_zone]`` on)
``parcel.csv``         the camera's sighting of the parcel each tick handed the mission (only with
                       ``[winch.camera]`` on a winch delivery)
``run.json``           format, configuration, fusion setup, mission frame and path, row counts
``flight.mcap``        every stream above, plus the camera frames the pad was detected in (JPEG)
                       with the marker corners, the EKF pose and its 1-sigma, and the planned
                       path, for Foxglove (:mod:`companion.flightlog.mcaplog`)
=====================  ==========================================================================

Replay (:mod:`companion.delivery.replay`) needs every input in the order the core saw it: every
input row carries ``seq``, one counter across all streams (samples, observations, fixes, request
results, commands, go/no-go verdicts and guidance ticks). Floats are written as shortest round-trip decimals, so
they read back as the same doubles.
"""

from __future__ import annotations

import enum
import functools
import itertools
import json
import logging
import math
import operator
import typing
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar

from companion.autopilot.types import TelemetrySample
from companion.flightlog.atomic import Room, write_text_atomic
from companion.flightlog.csvlog import CsvLog, close_logs
from companion.flightlog.hooks import FLIGHT, SAMPLES, LogHooks
from companion.flightlog.losses import forget as forget_losses
from companion.flightlog.losses import logs_incomplete, losses
from companion.flightlog.mcap_encoding import MCAP_FILE
from companion.flightlog.mcaplog import McapFlightLog
from companion.flightlog.streams import (
    DROP_ZONE_COLUMNS,
    DROP_ZONE_FILE,
    FORMAT,
    META_FILE,
    PARCEL_COLUMNS,
    PARCEL_FILE,
    SAMPLE_ENCODERS,
    SAMPLE_FIELDS,
    SAMPLE_FILES,
    STREAM_FILES,
    WINCH_COLUMNS,
    WINCH_FILE,
    WIND_COLUMNS,
    WIND_FILE,
    camera_row,
    ekf_row,
    guidance_row,
    transform_json,
    uwb_row,
)
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)


def _sample_writer(cls: type, seq: Any, lg: CsvLog, tap: Any = None) -> Any:
    """:meth:`FlightRecorder.on_sample`'s work for one sample type, in one call: the row
    :data:`~companion.flightlog.streams.SAMPLE_ENCODERS` builds (``seq`` taken from the iterator
    ``seq``) appended to ``lg``'s queue (:attr:`CsvLog.queue`, as :meth:`CsvLog.put` would,
    without its call). Types with flags or enums go through their encoder; the others build the
    tuple here. ``tap``: a :meth:`TelemetryTlog.sample_tap
    <companion.flightlog.telemetry_tlog.TelemetryTlog.sample_tap>` that gets
    every row too (queued even when the CSV's queue is full)."""
    fields_ = SAMPLE_FIELDS[cls]
    nxt = seq.__next__
    q = lg.queue
    append, mx, drop = q.append, lg.max_queue, lg.count_dropped
    if tap is not None:
        encode = SAMPLE_ENCODERS[cls]
        tap_append, clock, marker = tap

        def write_tapped(s: Any) -> None:
            row = encode(nxt(), s)
            tap_append((clock(), marker, cls, row))
            if len(q) < mx:
                append(row)
            else:
                drop()

        return write_tapped
    if any(t is bool or (isinstance(t, type) and issubclass(t, enum.Enum)) for _, t in fields_):
        encode = SAMPLE_ENCODERS[cls]

        def write_encoded(s: Any) -> None:
            row = encode(nxt(), s)  # a dropped row still takes its seq: replay sees the gap
            if len(q) < mx:
                append(row)
            else:
                drop()

        return write_encoded
    get = operator.attrgetter(*(n for n, _ in fields_))
    if len(fields_) == 1:

        def write_one(s: Any) -> None:
            row = (s.time_s, nxt(), get(s))
            if len(q) < mx:
                append(row)
            else:
                drop()

        return write_one

    def write(s: Any) -> None:
        row = (s.time_s, nxt(), *get(s))
        if len(q) < mx:
            append(row)
        else:
            drop()

    return write


def _json_safe(o: object) -> object:
    if isinstance(o, float) and not math.isfinite(o):
        return repr(o)
    if isinstance(o, dict):
        return {k: _json_safe(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_json_safe(v) for v in o]
    return o


# ---------------------------------------------------------------------------------------------

_F = typing.TypeVar("_F", bound=typing.Callable[..., None])


def _guarded(fn: _F) -> _F:
    """A hook of the control path: a failure to log is logged and counted (``errors``, and in
    ``run.json``), never raised into the flight."""

    @functools.wraps(fn)
    def hook(self: FlightRecorder, *args: Any) -> None:
        try:
            fn(self, *args)
        except Exception:
            self._hook_failed(fn.__name__)

    return typing.cast(_F, hook)


class FlightRecorder:
    """Writes the per-stream CSV logs of one flight into ``run_dir``.

    ``config`` is the :class:`companion.config.CompanionConfig` flown (saved in ``run.json`` for
    replay). The shell attaches it when it starts (:meth:`attach`). Close it in a
    ``finally`` (or use it as a context manager): every stream is flushed and closed, and
    ``run.json`` records the row counts. Calls after :meth:`close` are ignored.

    ``mcap``: also write ``flight.mcap`` (default :attr:`write_mcap`, True). ``hooks``: a
    bench's instruments (:class:`~companion.flightlog.hooks.LogHooks`), given to every log of the
    run folder: the streams, ``flight.mcap`` and the simulator's ``.tlog`` that shares the
    samples (:meth:`share_samples`); the telemetry listener (:meth:`on_sample`) is timed as
    :data:`~companion.flightlog.hooks.SAMPLES`. The other hooks are called by the shell's
    observer, timed there (:class:`~companion.delivery.hooks.ShellHooks`, stage ``"logging"``).
    """

    write_mcap: ClassVar[bool] = True

    def __init__(
        self,
        run_dir: str | Path,
        config: Any,
        max_queue: int = 200_000,
        mcap: bool | None = None,
        hooks: LogHooks = FLIGHT,
    ):
        self.run_dir = Path(run_dir)
        self.hooks = hooks
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._room = Room(self.run_dir)  # for run.json's last version on a disk the logs filled
        forget_losses(self.run_dir)  # what an earlier run in this folder lost is not this one's
        self._seq = itertools.count()
        self._closed = False
        self._telemetry: Any = None
        self.logs: dict[str, CsvLog] = {}
        self.ignored_after_close = 0
        self.errors = 0  # hook failures (the log is then incomplete; replay reports the seq gaps)
        streams = dict(STREAM_FILES)
        go_no_go = getattr(config, "go_no_go", None)
        winch = getattr(getattr(config, "mission", None), "delivery", "land") == "winch"
        if (go_no_go is not None and go_no_go.wind_limit_m_s > 0) or winch:  # the mission reads the wind
            streams[WIND_FILE] = WIND_COLUMNS
        if winch:  # the mission reads the winch's line length
            streams[WINCH_FILE] = WINCH_COLUMNS
            if config.winch.camera.enabled:  # and the camera's sightings of the parcel
                streams[PARCEL_FILE] = PARCEL_COLUMNS
        landing = getattr(config, "landing", None)
        if landing is not None and landing.drop_zone.enabled:  # the mission reads the drop-zone verdict
            streams[DROP_ZONE_FILE] = DROP_ZONE_COLUMNS
        self.meta: dict[str, Any] = {
            "format": FORMAT,
            "config": config.model_dump(mode="json"),
            "landing": None,  # set by attach(): does the shell run the landing fusion?
            "fusion": None,
            "mission": None,
            "streams": {name: list(cols) for name, cols in streams.items()},
            "closed": False,
            "mcap": None,
        }
        self.mcap: McapFlightLog | None = None
        self._planned_path: Any = None
        try:
            if self.write_mcap if mcap is None else mcap:
                self.mcap = McapFlightLog(self.run_dir / MCAP_FILE, streams, hooks)
                self.meta["mcap"] = MCAP_FILE
            for name, cols in streams.items():
                sink = self.mcap.stream_sink(name) if self.mcap is not None else None
                self.logs[name] = CsvLog(self.run_dir / name, cols, max_queue=max_queue, sink=sink, hooks=hooks)
            # the two hooks at the telemetry / setpoint rate queue their rows with no further checks
            self._shared_tlog: Any = None  # share_samples()
            self._make_sample_writers()
            self._put_setpoint = self.logs["setpoints.csv"].put
            self._write_meta()
        except BaseException:
            for lg in self.logs.values():
                lg.close()
            if self.mcap is not None:
                self.mcap.close()
            self._room.release()
            raise

    # ---- attachment ---------------------------------------------------------------------
    def attach(self, telemetry: Any, landing: bool, pad_sensors: bool | None = None) -> None:
        """Listen to a TelemetryCache (before anything else, so every sample gets a seq);
        ``landing``: the shell runs the landing fusion (replay must start it at the same tick);
        ``pad_sensors``: its landing kit carries a camera or a UWB (the pad lock the mission is
        handed is measured, not "no sensors"; None: not said, replay goes by the configuration)."""
        self._telemetry = telemetry
        self._listener = self.hooks.timed(SAMPLES, self.on_sample)  # bound once: removed as added
        telemetry.add_listener(self._listener)
        self.meta["landing"] = bool(landing)
        if pad_sensors is not None:
            self.meta["pad_sensors"] = bool(pad_sensors)
        self._write_meta()

    def detach(self) -> None:
        if self._telemetry is not None:
            self._telemetry.remove_listener(self._listener)
            tlog, self._shared_tlog = self._shared_tlog, None
            if tlog is not None:  # the .tlog outlives this recorder: it listens for itself again
                self._telemetry.add_listener(tlog.sample)
                self._make_sample_writers()
            self._telemetry = None

    def share_samples(self, telemetry: Any, tlog: Any) -> bool:
        """Queue the embedded simulator's ``.tlog`` records of the samples (``tlog``: a
        :class:`~companion.flightlog.telemetry_tlog.TelemetryTlog` on the same ``telemetry`` cache) from
        the rows this recorder builds anyway, so the ``.tlog`` needs no listener of its own and
        the hand-over carries each sample's values once (``companion bench log``). The file is
        the same. False (nothing changed) unless attached to ``telemetry`` and not sharing yet;
        the caller then lets ``tlog.sample`` listen. Undo with :meth:`unshare_samples` before the
        ``.tlog`` closes; if this recorder detaches first, it puts ``tlog.sample`` back on the
        cache."""
        if self._closed or self._telemetry is not telemetry or self._shared_tlog is not None:
            return False
        if self.hooks != FLIGHT:
            tlog.use_hooks(self.hooks)
        self._shared_tlog = tlog
        self._make_sample_writers()
        return True

    def unshare_samples(self, tlog: Any) -> None:
        """Stop queueing ``tlog``'s sample records (no-op unless :meth:`share_samples` gave it)."""
        if self._shared_tlog is tlog:
            self._shared_tlog = None
            self._make_sample_writers()

    def _make_sample_writers(self) -> None:
        tap = self._shared_tlog.sample_tap() if self._shared_tlog is not None else None
        self._sample_writers = {
            cls: _sample_writer(cls, self._seq, self.logs[name], tap) for cls, name in SAMPLE_FILES.items()
        }

    @property
    def closed(self) -> bool:
        return self._closed

    def _write(self, name: str, row: tuple[object, ...]) -> None:
        if self._closed:
            self.ignored_after_close += 1
            return
        self.logs[name].write(row)

    # ---- inputs of the core -------------------------------------------------------------
    def on_sample(self, sample: TelemetrySample) -> None:
        """TelemetryCache listener: every accepted autopilot sample (guarded like the other
        hooks, with the guard inline: this one runs at the telemetry rate)."""
        if self._closed:
            self.ignored_after_close += 1
            return
        try:
            self._sample_writers[type(sample)](sample)
        except KeyError:
            if type(sample) in self._sample_writers:
                self._hook_failed("on_sample")
            else:
                log.debug("no stream for %s", type(sample).__name__)
        except Exception:
            self._hook_failed("on_sample")

    def _hook_failed(self, hook: str) -> None:
        self.errors += 1
        if self.errors in (1, 10, 100, 1000):
            log.exception("flight log: %s failed (%d failures so far); the log is incomplete", hook, self.errors)

    @_guarded
    def on_marker(self, now_s: float, obs: Any, image: Any = None) -> None:
        """A pad observation about to be handed to the fusion; ``image``: the frame it was
        detected in (to the MCAP, JPEG-encoded on the writer thread, with ``obs.corners_px``)."""
        self._write("camera.csv", camera_row(next(self._seq), now_s, obs))
        if image is not None and self.mcap is not None and not self._closed:
            self.mcap.add_image(float(obs.time_s), image, getattr(obs, "corners_px", {}))

    @_guarded
    def on_uwb(self, now_s: float, fix: Any) -> None:
        """A UWB fix about to be handed to the fusion."""
        self._write("uwb.csv", uwb_row(next(self._seq), now_s, fix))

    @_guarded
    def on_result(self, now_s: float, kind: str, result: Any) -> None:
        """A request result about to be fed back to the mission (``RequestResult``)."""
        self._write(
            "requests.csv",
            (now_s, next(self._seq), result.id, kind, int(bool(result.ok)), result.error, int(bool(result.permanent))),
        )

    @_guarded
    def on_abort(self, now_s: float, reason: str) -> None:
        """An operator abort (signal) about to be applied to the mission."""
        self._write("commands.csv", (now_s, next(self._seq), "operator", "abort", reason, ""))

    @_guarded
    def on_command(self, now_s: float, kind: str, sender: str, reply: str) -> None:
        """A ground command just applied to the mission (``mission.command(now, kind, sender)``)."""
        self._write("commands.csv", (now_s, next(self._seq), "ground", kind, sender, reply))

    @_guarded
    def on_go_no_go(self, now_s: float, verdict: str, detail: str) -> None:
        """A go/no-go verdict about to be applied to the mission outside a guidance tick (the
        fence uploaded and read back: ``go``; refused: ``refuse``)."""
        self._write("commands.csv", (now_s, next(self._seq), "go_no_go", verdict, detail, ""))

    # ---- outputs of the core ------------------------------------------------------------
    @_guarded
    def on_tick(
        self,
        inp: Any,
        out: Any,
        setpoint: VelocitySetpoint | None,
        clamped: bool,
        mission: Any,
        fusion: Any,
    ) -> None:
        """One guidance tick, after the mission stepped (``inp``: MissionInputs, ``out``:
        MissionOutput, ``setpoint``: the clamped setpoint to stream)."""
        if self._closed:
            self.ignored_after_close += 1
            return
        seq = next(self._seq)
        self._write("guidance.csv", guidance_row(seq, inp, out, setpoint, clamped))
        if WIND_FILE in self.logs:
            w = inp.wind
            nan = math.nan
            wind = (w.time_s, w.north_m_s, w.east_m_s) if w is not None else (nan, nan, nan)
            self._write(WIND_FILE, (inp.time_s, seq, *wind))
        if WINCH_FILE in self.logs:
            ws = inp.winch
            nan = math.nan
            report = (
                (ws.time_s, ws.line_length_m, ws.speed_m_s, ws.flags, ws.tension_kg)
                if ws is not None
                else (nan, nan, nan, 0, nan)
            )
            self._write(WINCH_FILE, (inp.time_s, seq, *report))
        if DROP_ZONE_FILE in self.logs:
            self._write(DROP_ZONE_FILE, (inp.time_s, seq, inp.drop_zone.value if inp.drop_zone is not None else ""))
        if PARCEL_FILE in self.logs:
            ps = inp.parcel
            seen = (ps.time_s, *ps.tag_in_camera_m, ps.bottom_above_pad_m) if ps is not None else (math.nan,) * 5
            self._write(PARCEL_FILE, (inp.time_s, seq, *seen))
        for ev in out.events:
            self._write("events.csv", (ev.time_s, ev.kind.value, ev.phase.value, ev.detail))
        if fusion is not None:
            row = ekf_row(seq, inp.time_s, fusion)
            if row is not None:
                self._write("ekf.csv", row)
            if self.meta["fusion"] is None:
                self._record_fusion(fusion, inp.time_s)
        if self.mcap is not None and mission.path is not None and mission.path is not self._planned_path:
            self._planned_path = mission.path
            if mission.frame is not None:
                frame, path, z_start = mission.frame, mission.path, float(mission.z_start)  # replaced, never mutated
                self.mcap.add_path(
                    float(inp.time_s), lambda: [frame.point_to_ned(p) for p in path.sample(0.25, z_start)]
                )
        if self.meta["mission"] is None and mission.frame is not None and mission.path is not None:
            self.meta["mission"] = {
                "pad_ned_m": [float(v) for v in mission.frame.pad_ned],
                "heading_rad": float(mission.frame.heading_rad),
                "h_m": float(mission.path.h),
                "r_m": float(mission.path.r),
                "d_m": float(mission.path.d),
                "z_start_m": float(mission.z_start),
                "planned_at_s": float(inp.time_s),
            }
            self._write_meta()

    @_guarded
    def on_setpoint(self, now_s: float, sp: VelocitySetpoint) -> None:
        """A setpoint the stream sent to the autopilot."""
        if self._closed:
            self.ignored_after_close += 1
            return
        self._put_setpoint((now_s, sp.north_m_s, sp.east_m_s, sp.down_m_s, sp.yaw_rad))

    def _record_fusion(self, fusion: Any, now_s: float) -> None:
        s = fusion.setup
        self.meta["fusion"] = {
            "started_at_s": float(now_s),
            "T_world_pad": transform_json(s.T_world_pad),
            "T_body_camera": transform_json(s.T_body_camera),
            "T_pad_anchors": transform_json(s.T_pad_anchors),
            "ekf": s.ekf.model_dump(),
            "history_s": float(s.history_s),
            # only when on, so the logs of every other flight keep their bytes
            **(
                {
                    "velocity_bias_tau_s": float(s.velocity_bias_tau_s),
                    "velocity_bias_max_m_s": float(s.velocity_bias_max_m_s),
                    "velocity_bias_source": s.velocity_bias_source,
                }
                if s.velocity_bias_tau_s > 0.0
                else {}
            ),
            **({"level_pad": True} if s.level_pad else {}),
            **({"moving_pad": s.moving_pad.model_dump()} if s.moving_pad is not None else {}),
        }
        self._write_meta()

    # ---- closing --------------------------------------------------------------------------
    def _write_meta(self, sync: bool = False) -> None:
        """``run.json`` replaced whole (never torn); ``sync``: fsynced (at the close, not on the
        control path)."""
        text = json.dumps(_json_safe(self.meta), indent=1)
        try:
            write_text_atomic(self.run_dir / META_FILE, text, sync=sync)
        except OSError as err:
            if sync:  # the close's: reported there
                raise
            # in flight (a full disk): the previous version stays, the close writes the whole one
            log.error("%s: cannot rewrite it (%s); the previous version is kept", self.run_dir / META_FILE, err)
        if self.mcap is not None:
            self.mcap.add_meta(text)

    def close(self) -> None:
        """Flush and close every stream (idempotent); ``run.json`` gets the row counts."""
        if self._closed:
            return
        self._closed = True
        self.detach()
        errors = []
        try:  # every stream's last batch and close handed over together: one wait
            close_logs(self.logs.values())
        except Exception as err:  # one bad stream does not keep the others open (close_files)
            errors.append(f"{self.run_dir}: closing the streams: {err}")
        self.meta["closed"] = True
        self.meta["errors"] = self.errors
        self.meta["rows"] = {name: lg.written for name, lg in self.logs.items()}
        self.meta["dropped"] = {name: lg.dropped for name, lg in self.logs.items() if lg.dropped}
        if self.mcap is not None:
            self.meta["mcap_errors"] = self.mcap.errors
            self.meta["mcap_dropped_images"] = self.mcap.dropped_images
        faults = {x.path.name: x.cause.name for x in losses(self.run_dir) if x.path.parent == self.run_dir}
        if faults:  # only then: a normal flight's run.json keeps its bytes
            self.meta["storage_faults"] = faults
        self._room.release()
        try:
            self._write_meta(sync=True)
        except OSError as err:
            errors.append(f"{self.run_dir / META_FILE}: {err}")
        if self.mcap is not None:
            self.mcap.close()
        for e in errors:
            log.error("flight log: %s", e)

    @property
    def logs_incomplete(self) -> bool:
        """Whether a log of this run folder lost rows so far (a full disk, an I/O error, a full
        queue: :mod:`companion.flightlog.losses`, known within one hand-over); not for the
        control path's every tick (it takes a lock and scans the losses)."""
        return logs_incomplete(self.run_dir)

    def __enter__(self) -> FlightRecorder:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


class NullRecorder(FlightRecorder):
    """A :class:`FlightRecorder` that opens and closes the run folder as usual (the streams,
    ``flight.mcap``, ``run.json``) and logs nothing: every hook does nothing, and the
    simulator's ``.tlog`` that would share the samples takes no records either
    (:meth:`TelemetryTlog.take_no_records
    <companion.flightlog.telemetry_tlog.TelemetryTlog.take_no_records>`). ``companion bench log``:
    what opening and closing the logs cost a flight."""

    def share_samples(self, telemetry: Any, tlog: Any) -> bool:
        if self.hooks != FLIGHT:
            tlog.use_hooks(self.hooks)
        tlog.take_no_records()
        return False  # its own (no-op) sample hook listens

    def on_sample(self, sample: TelemetrySample) -> None:
        pass

    def on_marker(self, now_s: float, obs: Any, image: Any = None) -> None:
        pass

    def on_uwb(self, now_s: float, fix: Any) -> None:
        pass

    def on_result(self, now_s: float, kind: str, result: Any) -> None:
        pass

    def on_abort(self, now_s: float, reason: str) -> None:
        pass

    def on_command(self, now_s: float, kind: str, sender: str, reply: str) -> None:
        pass

    def on_go_no_go(self, now_s: float, verdict: str, detail: str) -> None:
        pass

    def on_tick(
        self, inp: Any, out: Any, setpoint: VelocitySetpoint | None, clamped: bool, mission: Any, fusion: Any
    ) -> None:
        pass

    def on_setpoint(self, now_s: float, sp: VelocitySetpoint) -> None:
        pass
