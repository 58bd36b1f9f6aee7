"""Replay a recorded flight through the same core code, and check it is bit for bit the same.

The recorder (:mod:`companion.flightlog.recorder`) numbers every input of the core with one
counter, ``seq``: autopilot samples, pad observations, UWB fixes, request results, operator and
ground commands, and guidance ticks. Replay merges the input streams by ``seq`` and feeds them,
in that order, to fresh core objects built from the recorded configuration:

- samples go through a :class:`~companion.autopilot.interface.TelemetryCache` (the fusion listens
  to it from the tick it was started at, as in flight);
- pad observations and UWB fixes go to :class:`~companion.delivery.fusion.LandingFusion`;
- request results, aborts, ground commands and go/no-go verdicts to
  :class:`~companion.delivery.mission.DeliveryMission`;
- each tick repeats the shell's guidance step (:meth:`companion.delivery.shell.DeliveryShell._guidance_loop`):
  autopilot pose estimate, fusion start once the mission has a frame, the fused estimate on the
  way to the pad, the wind estimate the tick handed the mission (``wind.csv``, written when the
  wind go/no-go is on), ``mission.step``, the velocity-bias correction and the setpoint clamp.

The replayed ``ekf.csv``, ``guidance.csv`` and ``events.csv`` are written (same columns) and
compared cell by cell with the recorded ones: floats are written as shortest round-trip decimals,
so equal text means equal doubles.
"""

from __future__ import annotations

import enum
import itertools
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar, cast

import numpy as np

from companion.delivery.gonogo import GoNoGoVerdict
from companion.events import CommandKind
from companion.flightlog.csv_file import format_cell
from companion.flightlog.csvlog import CsvLog
from companion.flightlog.losses import LossCause
from companion.flightlog.reader import LogFormatError, Table, open_table, read_meta
from companion.flightlog.streams import (
    DROP_ZONE_COLUMNS,
    DROP_ZONE_FILE,
    EKF_COLUMNS,
    EVENT_COLUMNS,
    GUIDANCE_COLUMNS,
    META_FILE,
    PARCEL_COLUMNS,
    PARCEL_FILE,
    SAMPLE_FILES,
    STREAM_FILES,
    WINCH_COLUMNS_BEFORE_TENSION,
    WINCH_FILE,
    WIND_COLUMNS,
    WIND_FILE,
    PadObservation,
    ekf_row,
    guidance_row,
    sample_fields,
    transform_from_json,
)

log = logging.getLogger(__name__)

E = TypeVar("E", bound=enum.Enum)


# Columns added after the log format was first released, with the value older logs imply.
OPTIONAL_COLUMNS: dict[tuple[str, str], Any] = {
    ("requests.csv", "permanent"): False,
    ("ap_home.csv", "north_m"): 0.0,
    ("ap_home.csv", "east_m"): 0.0,
    ("ap_home.csv", "down_m"): 0.0,
    ("uwb.csv", "hdop"): math.nan,
    ("uwb.csv", "vdop"): math.nan,
    ("uwb.csv", "vertical_weak"): False,
}


# ---------------------------------------------------------------------------------------------
# the merged input stream


class InputKind(enum.Enum):
    """What a recorded input of the core is, and so where replay feeds it (its value names it in
    messages)."""

    SAMPLE = "sample"  # an autopilot sample (the ap_*.csv files): the telemetry cache
    MARKER = "marker"  # a pad observation (camera.csv): the landing fusion
    UWB = "uwb"  # a UWB fix (uwb.csv): the landing fusion
    RESULT = "result"  # a request's result (requests.csv): the mission
    ABORT = "abort"  # an operator abort (commands.csv): the mission
    COMMAND = "command"  # a ground or GCS command (commands.csv): the mission
    GO_NO_GO = "go_no_go"  # a go/no-go verdict reached outside a tick (commands.csv): the mission
    TICK = "tick"  # a guidance tick (guidance.csv)


# commands.csv's sources -> input kinds: operator aborts, ground commands, go/no-go verdicts
# reached outside a tick (the fence upload; logs before them have none)
_COMMAND_SOURCES = {"operator": InputKind.ABORT, "ground": InputKind.COMMAND, "go_no_go": InputKind.GO_NO_GO}


@dataclass(frozen=True)
class _Input:
    seq: int
    kind: InputKind
    payload: Any
    where: str  # file:line, for messages


def _int(t: Table, k: int, c: str) -> int:
    return int(t.value(k, c, int))


def _sample_inputs(t: Table, name: str, cls: Any) -> list[_Input]:
    fields_ = sample_fields(cls)
    out = []
    for k in range(len(t)):
        sample = cls(
            t.value(k, "time_s"),
            *(t.value(k, n, typ) if n in t.index else OPTIONAL_COLUMNS[(name, n)] for n, typ in fields_),
        )
        out.append(_Input(_int(t, k, "seq"), InputKind.SAMPLE, sample, f"{name}:{k + 2}"))
    return out


def _marker_inputs(t: Table) -> list[_Input]:
    from companion.geometry.se3 import Transform

    out = []
    for k in range(len(t)):
        R = np.array([t.value(k, f"r{i}{j}") for i in range(3) for j in range(3)], dtype=float).reshape(3, 3)
        tv = np.array([t.value(k, c) for c in ("t_x_m", "t_y_m", "t_z_m")], dtype=float)
        obs = PadObservation(
            t.value(k, "time_s"),
            Transform(R, tv),
            t.value(k, "ambiguous", bool),
            tuple(t.text(k, "markers").split()),
            t.value(k, "reprojection_error_px"),
        )
        out.append(_Input(_int(t, k, "seq"), InputKind.MARKER, obs, f"camera.csv:{k + 2}"))
    return out


def _uwb_inputs(t: Table) -> list[_Input]:
    from companion.uwb.measurements import UwbFix

    out = []
    for k in range(len(t)):
        fix = UwbFix(
            t.value(k, "time_s"),
            t.value(k, "x_m"),
            t.value(k, "y_m"),
            t.value(k, "z_m"),
            t.value(k, "pdop"),
            t.value(k, "residual_rms_m"),
            tuple(t.text(k, "anchors_used").split()),
            t.text(k, "frame"),
            hdop=t.value(k, "hdop") if "hdop" in t.index else OPTIONAL_COLUMNS[("uwb.csv", "hdop")],
            vdop=t.value(k, "vdop") if "vdop" in t.index else OPTIONAL_COLUMNS[("uwb.csv", "vdop")],
            vertical_weak=(
                t.value(k, "vertical_weak", bool)
                if "vertical_weak" in t.index
                else OPTIONAL_COLUMNS[("uwb.csv", "vertical_weak")]
            ),
        )
        out.append(_Input(_int(t, k, "seq"), InputKind.UWB, fix, f"uwb.csv:{k + 2}"))
    return out


def _result_inputs(t: Table) -> list[_Input]:
    from companion.delivery.mission import RequestResult

    out = []
    for k in range(len(t)):
        permanent = "permanent" in t.index and t.value(k, "permanent", bool)
        res = RequestResult(_int(t, k, "id"), t.value(k, "ok", bool), t.text(k, "error"), permanent)
        out.append(_Input(_int(t, k, "seq"), InputKind.RESULT, res, f"requests.csv:{k + 2}"))
    return out


def _command_inputs(t: Table) -> list[_Input]:
    out = []
    for k in range(len(t)):
        src = t.text(k, "source")
        if src not in _COMMAND_SOURCES:
            raise LogFormatError(
                f"{t.path}: line {k + 2}, column 'source': {src!r} is not one of "
                + ", ".join(repr(s) for s in _COMMAND_SOURCES)
            )
        input_kind = _COMMAND_SOURCES[src]
        kind = t.text(k, "kind")
        parsed: Any = kind  # an operator abort's kind is not read
        if input_kind is InputKind.GO_NO_GO:
            parsed = _token(t, k, GoNoGoVerdict, kind)
        elif input_kind is InputKind.COMMAND:
            parsed = _token(t, k, CommandKind, kind)
        cmd = (t.value(k, "time_s"), parsed, t.text(k, "detail"), t.text(k, "reply"))
        out.append(_Input(_int(t, k, "seq"), input_kind, cmd, f"commands.csv:{k + 2}"))
    return out


def _token(t: Table, k: int, kinds: type[E], text: str) -> E:
    """commands.csv's ``kind`` column as the enum it names (the log's text is read here only)."""
    try:
        return kinds(text)
    except ValueError:
        allowed = ", ".join(repr(m.value) for m in kinds)
        raise LogFormatError(f"{t.path}: line {k + 2}, column 'kind': {text!r} is not one of {allowed}") from None


def _tick_inputs(t: Table) -> list[_Input]:
    return [
        _Input(
            _int(t, k, "seq"),
            InputKind.TICK,
            (t.value(k, "time_s"), t.value(k, "link_ok", bool)),
            f"guidance.csv:{k + 2}",
        )
        for k in range(len(t))
    ]


def read_inputs(run_dir: Path) -> tuple[list[_Input], dict[str, Table]]:
    """Every recorded input of the core in ``seq`` order, and the tables read."""
    tables: dict[str, Table] = {}

    def table(name: str) -> Table:
        # logs written before a column was added still replay (with its default)
        required = [c for c in STREAM_FILES[name] if (name, c) not in OPTIONAL_COLUMNS]
        tables[name] = open_table(run_dir, name, required)
        return tables[name]

    inputs: list[_Input] = []
    for cls, name in SAMPLE_FILES.items():
        inputs += _sample_inputs(table(name), name, cls)
    inputs += _marker_inputs(table("camera.csv"))
    inputs += _uwb_inputs(table("uwb.csv"))
    inputs += _result_inputs(table("requests.csv"))
    inputs += _command_inputs(table("commands.csv"))
    inputs += _tick_inputs(table("guidance.csv"))
    for name in ("ekf.csv", "events.csv"):
        table(name)
    inputs.sort(key=lambda i: i.seq)
    for a, b in itertools.pairwise(inputs):
        if a.seq == b.seq:
            raise LogFormatError(f"{run_dir}: seq {a.seq} appears twice ({a.where} and {b.where})")
    return inputs, tables


# ---------------------------------------------------------------------------------------------
# the replaying shell


@dataclass
class _LogLink:
    """Stands in for the autopilot while the shell's core objects are built for replay."""

    telemetry: Any


class _ReplayShell:
    """The synchronous part of :class:`companion.delivery.shell.DeliveryShell`, fed from the log."""

    def __init__(self, meta: dict[str, Any], run_dir: Path):
        from companion.autopilot.interface import TelemetryCache
        from companion.config import ConfigError, config_from_dict
        from companion.delivery.shell import DeliveryShell

        try:
            self.config = config_from_dict(meta["config"], str(run_dir / META_FILE))
        except ConfigError as err:
            raise LogFormatError(
                f"{err.source}: recorded configuration invalid (a log from another version of companion?): "
                + "; ".join(err.problems)
            ) from None
        self.meta = meta
        self.run_dir = run_dir
        self.telemetry = TelemetryCache()
        # the mission and the autopilot-pose estimator exactly as the shell builds them (its
        # constructor starts nothing; the link is never used)
        built = DeliveryShell(self.config, cast(Any, _LogLink(self.telemetry)))
        self.mission = built.mission
        self.estimator = built.estimator
        self.velocity_bias = built._velocity_bias  # [mission] velocity_bias_tau_s (None: off)
        self.fusion: Any = None
        self._fusion_pad_index = 0  # mission.pad_index the fusion was started for
        self.landing = bool(meta.get("landing"))
        self.notes: list[str] = []
        # the wind estimate each tick handed the mission (wind.csv), when the mission reads one
        self.wind_by_seq: dict[int, Any] = {}
        if self.mission.wind is not None or self.mission.winch_cfg is not None:
            self._read_wind()
        # the winch's report each tick handed the mission (winch.csv), for a winch delivery
        self.winch_by_seq: dict[int, Any] = {}
        if self.mission.winch_cfg is not None:
            self._read_winch()
        # the drop-zone verdict each tick handed the mission (drop_zone.csv), with the check on
        self.drop_zone_by_seq: dict[int, Any] = {}
        if self.config.landing.drop_zone.enabled:
            self._read_drop_zone()
        # the camera's sighting of the parcel each tick handed the mission (parcel.csv), [winch.camera]
        self.parcel_by_seq: dict[int, Any] = {}
        if self.mission.winch_cfg is not None and self.config.winch.camera.enabled:
            self._read_parcel()

    def _read_wind(self) -> None:
        from companion.autopilot.types import Wind

        if not (self.run_dir / WIND_FILE).exists() and WIND_FILE not in (self.meta.get("streams") or {}):
            self.notes.append(
                f"{WIND_FILE} missing (a log from before it was recorded): the wind go/no-go is replayed "
                "without the autopilot's wind estimate"
            )
            return
        t = open_table(self.run_dir, WIND_FILE, WIND_COLUMNS)
        for k in range(len(t)):
            w = (t.value(k, "wind_time_s"), t.value(k, "north_m_s"), t.value(k, "east_m_s"))
            self.wind_by_seq[_int(t, k, "seq")] = Wind(*w) if math.isfinite(w[0]) else None

    def _read_winch(self) -> None:
        from companion.autopilot.winch import WinchStatus

        if not (self.run_dir / WINCH_FILE).exists() and WINCH_FILE not in (self.meta.get("streams") or {}):
            self.notes.append(f"{WINCH_FILE} missing: the winch delivery is replayed without the winch's reports")
            return
        t = open_table(self.run_dir, WINCH_FILE, WINCH_COLUMNS_BEFORE_TENSION)
        tension = "tension_kg" in t.index  # (a log from before it was recorded: none reported)
        for k in range(len(t)):
            w = (t.value(k, "winch_time_s"), t.value(k, "line_length_m"), t.value(k, "speed_m_s"))
            ok = math.isfinite(w[0])
            kg = t.value(k, "tension_kg") if tension else math.nan
            self.winch_by_seq[_int(t, k, "seq")] = WinchStatus(*w, _int(t, k, "flags"), kg) if ok else None

    def _read_drop_zone(self) -> None:
        from companion.vision.drop_zone import DropZoneVerdict

        if not (self.run_dir / DROP_ZONE_FILE).exists() and DROP_ZONE_FILE not in (self.meta.get("streams") or {}):
            self.notes.append(f"{DROP_ZONE_FILE} missing: the flight is replayed without the drop-zone verdicts")
            return
        t = open_table(self.run_dir, DROP_ZONE_FILE, DROP_ZONE_COLUMNS)
        known = {v.value: v for v in DropZoneVerdict}
        for k in range(len(t)):
            text = t.text(k, "verdict")
            if text and text not in known:
                raise LogFormatError(
                    f"{self.run_dir / DROP_ZONE_FILE} row {k + 2}: verdict {text!r} is not one of {sorted(known)}"
                )
            self.drop_zone_by_seq[_int(t, k, "seq")] = known[text] if text else None

    def _read_parcel(self) -> None:
        from companion.vision.parcel_tag import ParcelSighting

        if not (self.run_dir / PARCEL_FILE).exists() and PARCEL_FILE not in (self.meta.get("streams") or {}):
            self.notes.append(f"{PARCEL_FILE} missing: the flight is replayed without the camera's parcel sightings")
            return
        t = open_table(self.run_dir, PARCEL_FILE, PARCEL_COLUMNS)
        for k in range(len(t)):
            ts = t.value(k, "sighting_time_s")
            tag = (t.value(k, "tag_x_m"), t.value(k, "tag_y_m"), t.value(k, "tag_z_m"))
            seen = ParcelSighting(ts, tag, t.value(k, "bottom_above_pad_m")) if math.isfinite(ts) else None
            self.parcel_by_seq[_int(t, k, "seq")] = seen

    def _start_fusion(self, now: float) -> None:
        from companion.config import MovingPadConfig
        from companion.delivery.fusion import FusionSetup, LandingFusion
        from companion.delivery.pad_heading import pad_yaw_and_tolerance_rad
        from companion.estimation.ekf import EkfConfig
        from companion.geometry.mounts import pad_pose_ned

        rec = self.meta.get("fusion")
        if not isinstance(rec, dict):
            raise LogFormatError(
                f"{self.run_dir / META_FILE}: the landing fusion started at t = {now} but its setup "
                "(key 'fusion') was not recorded"
            )
        assert self.mission.frame is not None
        pad = self.mission.frame.pad_ned
        yaw, heading_tol = pad_yaw_and_tolerance_rad(self.config.mission, self.mission.pad_index)
        T_world_pad = pad_pose_ned(float(pad[0]), float(pad[1]), float(pad[2]), yaw_rad=yaw)
        try:
            setup = FusionSetup(
                T_world_pad=T_world_pad,
                heading_tolerance_rad=heading_tol,
                T_body_camera=transform_from_json(rec["T_body_camera"]),
                T_pad_anchors=transform_from_json(rec["T_pad_anchors"]),
                ekf=EkfConfig(**rec["ekf"]),
                history_s=float(rec["history_s"]),
                velocity_bias_tau_s=float(rec.get("velocity_bias_tau_s", 0.0)),
                velocity_bias_max_m_s=float(rec.get("velocity_bias_max_m_s", 1.0)),
                velocity_bias_source=str(rec.get("velocity_bias_source", "autopilot")),
                level_pad=bool(rec.get("level_pad", False)),
                moving_pad=MovingPadConfig(**rec["moving_pad"]) if "moving_pad" in rec else None,
            )
        except (KeyError, TypeError, ValueError) as err:
            raise LogFormatError(f"{self.run_dir / META_FILE}: key 'fusion': {type(err).__name__}: {err}") from None
        if self.fusion is not None:
            # diverted: the fusion starts again on the alternate pad, as LandingSensing.start_fusion
            self.telemetry.remove_listener(self.fusion.on_sample)
            self._fusion_pad_index = self.mission.pad_index
            self.fusion = LandingFusion(setup, now)
            self.telemetry.add_listener(self.fusion.on_sample)
            return
        self._fusion_pad_index = self.mission.pad_index
        recorded_pad = transform_from_json(rec["T_world_pad"])
        if not (np.array_equal(recorded_pad.t, T_world_pad.t) and np.array_equal(recorded_pad.R, T_world_pad.R)):
            self.notes.append(
                f"the replayed mission put the pad at {T_world_pad.t.tolist()}, the flight at {recorded_pad.t.tolist()}"
            )
        if rec.get("started_at_s") != now:
            self.notes.append(f"fusion started at t = {now} in replay, {rec.get('started_at_s')} in flight")
        self.fusion = LandingFusion(setup, now)
        self.telemetry.add_listener(self.fusion.on_sample)

    def feed(self, inp: _Input) -> Any:
        k = inp.kind
        if k is InputKind.SAMPLE:
            self.telemetry.push(inp.payload)
        elif k is InputKind.MARKER or k is InputKind.UWB:
            if self.fusion is None:
                raise LogFormatError(
                    f"{inp.where}: a {k.value} input before the landing fusion started (seq {inp.seq})"
                )
            (self.fusion.on_marker if k is InputKind.MARKER else self.fusion.on_uwb)(inp.payload)
        elif k is InputKind.RESULT:
            self.mission.on_result(inp.payload)
        elif k is InputKind.ABORT:
            now, _kind, reason, _reply = inp.payload
            self.mission.abort(now, reason)
        elif k is InputKind.GO_NO_GO:
            now, verdict, detail, _reply = inp.payload
            refused = verdict is GoNoGoVerdict.REFUSE
            (self.mission.refuse if refused else self.mission.go_no_go)(now, detail)
        elif k is InputKind.COMMAND:
            now, kind, sender, reply = inp.payload
            got = self.mission.command(now, kind, sender)
            if got != reply:
                self.notes.append(
                    f"{inp.where}: ground command {kind.value!r} replied {got!r} in replay, {reply!r} in flight"
                )
        elif k is InputKind.TICK:
            now, link_ok = inp.payload
            return self.tick(
                now,
                link_ok,
                wind=self.wind_by_seq.get(inp.seq),
                winch=self.winch_by_seq.get(inp.seq),
                drop_zone=self.drop_zone_by_seq.get(inp.seq),
                parcel=self.parcel_by_seq.get(inp.seq),
            )
        return None

    def _pad_lock(self, now: float) -> Any:
        """As LandingSensing.pad_lock, from the recorded kit and the replayed fusion."""
        from companion.delivery.padlock import NO_SENSORS, PadLock, measure_pad_lock

        lc = self.config.landing
        # the kit the shell had (run.json; logs before it: the kit the configuration builds)
        sensors = self.meta.get("pad_sensors")
        if sensors is None:
            sensors = self.landing and (lc.use_camera or lc.use_uwb)
        if not sensors:
            return NO_SENSORS
        if self.fusion is None:
            return PadLock(now, math.inf, math.inf)
        return measure_pad_lock(self.fusion, now)

    def tick(
        self,
        now: float,
        link_ok: bool,
        wind: Any = None,
        winch: Any = None,
        drop_zone: Any = None,
        parcel: Any = None,
    ) -> tuple[Any, Any, Any, bool]:
        # keep in step with DeliveryShell._guidance_loop (the replay test fails when they diverge)
        from companion.delivery.mission import MissionInputs
        from companion.delivery.pad_heading import heading_observation_age_s, landing_heading_rad
        from companion.guidance.limits import clamp_velocity

        mission, tc = self.mission, self.telemetry
        gps_frame = self.estimator.update(tc.position_ned, tc.attitude)
        if self.landing:
            if self.fusion is None and mission.frame is not None:
                self._start_fusion(now)
            elif self.fusion is not None and mission.pad_index != self._fusion_pad_index:
                self._start_fusion(now)  # diverted: again on the alternate pad
        fused = self.fusion.estimate() if self.fusion is not None else None
        estimate = mission.guidance_estimate(gps_frame, fused, now)
        heading_est = self.fusion.heading if self.fusion is not None else None
        heading = landing_heading_rad(self.config.mission, mission.pad_index, heading_est)
        inp = MissionInputs(
            now,
            estimate,
            tc.status,
            tc.home,
            link_ok,
            self._pad_lock(now),
            wind=wind,
            pad_heading_rad=heading,
            pad_heading_age_s=heading_observation_age_s(heading_est, now),
            autopilot_yaw_rad=tc.attitude.yaw_rad if tc.attitude is not None else None,
            winch=winch,
            drop_zone=drop_zone,
            pad_velocity_ne=self.fusion.pad_velocity_ne if self.fusion is not None else None,
            parcel=parcel,
        )
        out = mission.step(inp)
        setpoint, clamped = None, False
        if self.velocity_bias is not None:
            self.velocity_bias.update(tc.position_ned, self.fusion.locked_position if self.fusion is not None else None)
        if out.setpoint is not None:
            pos = estimate.position_ned if estimate else None
            sp = self.velocity_bias.correct(out.setpoint) if self.velocity_bias is not None else out.setpoint
            res = clamp_velocity(sp, self.config.limits, pos)
            setpoint, clamped = res.setpoint, res.clamped
        return inp, out, setpoint, clamped


# ---------------------------------------------------------------------------------------------
# comparison


@dataclass
class StreamComparison:
    name: str
    recorded_rows: int
    replayed_rows: int
    differing_rows: int = 0
    max_abs_diff: dict[str, float] = field(default_factory=dict)  # per float column that differs
    text_diffs: dict[str, int] = field(default_factory=dict)  # per non-float column: differing cells
    first_difference: str = ""

    @property
    def identical(self) -> bool:
        return self.recorded_rows == self.replayed_rows and self.differing_rows == 0


def _cells(row: Sequence[object]) -> list[str]:
    return [format_cell(v) for v in row]


def _compare_row(
    cmp: StreamComparison, header: Sequence[str], rec: Sequence[str], rep: Sequence[str], where: str
) -> None:
    differs = False
    for col, a, b in zip(header, rec, rep, strict=True):
        if a == b:
            continue
        differs = True
        try:
            fa, fb = float(a), float(b)
            d = abs(fa - fb) if math.isfinite(fa) and math.isfinite(fb) else math.inf
            cmp.max_abs_diff[col] = max(cmp.max_abs_diff.get(col, 0.0), d)
        except ValueError:
            cmp.text_diffs[col] = cmp.text_diffs.get(col, 0) + 1
        if not cmp.first_difference:
            cmp.first_difference = f"{where}, column {col!r}: recorded {a!r}, replayed {b!r}"
    if differs:
        cmp.differing_rows += 1


@dataclass
class ReplayResult:
    run_dir: str
    out_dir: str
    inputs: int
    ticks: int
    missing_seq: int
    streams: dict[str, StreamComparison]
    notes: list[str]
    wall_s: float
    torn: list[str] = field(default_factory=list)

    @property
    def identical(self) -> bool:
        return all(c.identical for c in self.streams.values()) and self.missing_seq == 0

    def lines(self) -> list[str]:
        out = [
            f"replayed {self.inputs} inputs ({self.ticks} guidance ticks) from {self.run_dir} in {self.wall_s:.2f} s",
        ]
        if self.missing_seq:
            out.append(f"  {self.missing_seq} input(s) missing from the log (seq gaps): the replay cannot be exact")
        for t in self.torn:
            out.append(f"  {t}: torn last line dropped")
        for c in self.streams.values():
            if c.identical:
                out.append(f"  {c.name}: {c.recorded_rows} rows, identical bit for bit")
                continue
            out.append(
                f"  {c.name}: DIFFERENT: {c.recorded_rows} rows recorded, {c.replayed_rows} replayed, "
                f"{c.differing_rows} rows differ"
            )
            for col, d in sorted(c.max_abs_diff.items(), key=lambda kv: -kv[1])[:8]:
                out.append(f"    max |recorded - replayed| {col}: {d:.3g}")
            for col, n in c.text_diffs.items():
                out.append(f"    {col}: {n} cells differ")
            if c.first_difference:
                out.append(f"    first: {c.first_difference}")
        out.extend(f"  note: {n}" for n in self.notes)
        out.append(f"  replayed logs: {self.out_dir}")
        out.append("IDENTICAL: the replay reproduces the flight bit for bit" if self.identical else "NOT IDENTICAL")
        return out


def _storage_notes(meta: dict[str, Any]) -> list[str]:
    """What run.json says of log files stopped in flight (a full disk: named by their cause) and
    of a recorder never closed."""
    notes = []
    faults = meta.get("storage_faults") or {}
    if faults:
        causes = sorted({LossCause[c].value for c in faults.values() if c in LossCause.__members__})
        notes.append(
            f"run.json: {len(faults)} log file(s) stopped in flight ({', '.join(causes) or 'storage fault'}): "
            "the replay covers the flight up to there"
        )
    if not meta.get("closed"):
        notes.append(
            "run.json says the recorder was never closed (the process died, or the disk was full when it closed): "
            "the log may end early"
        )
    return notes


def replay_run(
    run_dir: str | Path, out_dir: str | Path | None = None, progress: Callable[[int, int], None] | None = None
) -> ReplayResult:
    """Replay ``run_dir``; write the replayed ekf.csv, guidance.csv and events.csv into
    ``out_dir`` (default ``run_dir/replay``) and compare them with the recorded ones."""
    run = Path(run_dir)
    if not run.is_dir():
        raise LogFormatError(f"{run}: not a folder")
    out = Path(out_dir) if out_dir is not None else run / "replay"
    if out.resolve() == run.resolve():
        raise LogFormatError(f"{out}: the replay must not overwrite the recorded logs; choose another --out")
    t0 = time.perf_counter()
    meta = read_meta(run)
    inputs, tables = read_inputs(run)
    shell = _ReplayShell(meta, run)
    if meta.get("errors"):
        shell.notes.append(f"the recorder reported {meta['errors']} logging failure(s): the log is incomplete")
    shell.notes.extend(_storage_notes(meta))
    seqs = [i.seq for i in inputs]
    missing = (seqs[-1] + 1 - len(seqs)) if seqs else 0
    rec_ekf = {int(tables["ekf.csv"].text(k, "seq")): tables["ekf.csv"].rows[k] for k in range(len(tables["ekf.csv"]))}
    rec_guid = tables["guidance.csv"]
    rec_events = tables["events.csv"]
    cmp_ekf = StreamComparison("ekf.csv", len(tables["ekf.csv"]), 0)
    cmp_guid = StreamComparison("guidance.csv", len(rec_guid), 0)
    cmp_ev = StreamComparison("events.csv", len(rec_events), 0)
    ticks = 0
    logs = {
        "ekf.csv": CsvLog(out / "ekf.csv", EKF_COLUMNS),
        "guidance.csv": CsvLog(out / "guidance.csv", GUIDANCE_COLUMNS),
        "events.csv": CsvLog(out / "events.csv", EVENT_COLUMNS),
    }
    try:
        for n, item in enumerate(inputs):
            res = shell.feed(item)
            if progress is not None and n % 2000 == 0:
                progress(n, len(inputs))
            if res is None:
                continue
            inp, mout, setpoint, clamped = res
            g = guidance_row(item.seq, inp, mout, setpoint, clamped)
            logs["guidance.csv"].write(g)
            _compare_row(cmp_guid, GUIDANCE_COLUMNS, rec_guid.rows[ticks], _cells(g), f"guidance.csv line {ticks + 2}")
            ticks += 1
            cmp_guid.replayed_rows += 1
            for ev in mout.events:
                row = (ev.time_s, ev.kind.value, ev.phase.value, ev.detail)
                logs["events.csv"].write(row)
                k = cmp_ev.replayed_rows
                cmp_ev.replayed_rows += 1
                if k < len(rec_events):
                    _compare_row(cmp_ev, EVENT_COLUMNS, rec_events.rows[k], _cells(row), f"events.csv line {k + 2}")
            if shell.fusion is not None:
                e = ekf_row(item.seq, inp.time_s, shell.fusion)
                if e is not None:
                    logs["ekf.csv"].write(e)
                    cmp_ekf.replayed_rows += 1
                    recorded = rec_ekf.get(item.seq)
                    if recorded is None:
                        cmp_ekf.differing_rows += 1
                        cmp_ekf.first_difference = cmp_ekf.first_difference or f"seq {item.seq}: no recorded row"
                    else:
                        _compare_row(cmp_ekf, EKF_COLUMNS, recorded, _cells(e), f"ekf.csv seq {item.seq}")
    finally:
        for lg in logs.values():
            lg.close()
    if progress is not None:
        progress(len(inputs), len(inputs))
    return ReplayResult(
        run_dir=str(run),
        out_dir=str(out),
        inputs=len(inputs),
        ticks=ticks,
        missing_seq=missing,
        streams={c.name: c for c in (cmp_ekf, cmp_guid, cmp_ev)},
        notes=shell.notes,
        wall_s=time.perf_counter() - t0,
        torn=[name for name, t in tables.items() if t.torn],
    )
