"""Fly the delivery mission on the embedded simulator and score it against simulator truth.

The application cannot tell the simulator from a vehicle: :class:`companion.delivery.shell.DeliveryShell`
runs unchanged against :class:`SimAutopilot`. Truth (what the vehicle really did) is read from
the simulator only here, for scoring: path distance, landing error on the true pad.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from companion.autopilot.interface import Autopilot
from companion.delivery.hooks import ShellHooks
from companion.delivery.mission import FailureKind, MissionOutput
from companion.delivery.observers import FLIGHT_LOG_COLUMNS
from companion.delivery.planning import pad_config_ned, pad_position_ned
from companion.delivery.shell import DeliveryShell
from companion.delivery.signals import abort_on_signals
from companion.events import Phase
from companion.flightlog.atomic import write_text_atomic
from companion.flightlog.csvlog import CsvLog
from companion.flightlog.hooks import FLIGHT, LogHooks, row_stage
from companion.flightlog.recorder import FlightRecorder
from companion.geometry.earth import GeoPoint
from companion_sitl.autopilot import SimAutopilot
from companion_sitl.clock import run_virtual
from companion_sitl.landing_sensors import CameraPlayback, sim_landing_kit
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.pad_motion import PadTrack, pad_track
from companion_sitl.params import SimulatedConfig
from companion_sitl.scoring import REFERENCE, PathScorer, heading_error_deg, rms, simulated_pad, true_pad_heading_rad
from companion_sitl.vehicle import SimVehicle

log = logging.getLogger(__name__)

TRUTH_COLUMNS = (
    "time_s",
    "phase",
    "true_north_m",
    "true_east_m",
    "true_down_m",
    "true_mission_x_m",
    "true_mission_y_m",
    "true_mission_z_m",
    "true_path_distance_m",
    "est_lyapunov_m2",
    "true_planned_path_distance_m",
)


@dataclass
class DemoResult:
    delivered: bool
    returned: bool
    phase: str
    failure: str
    flight_time_s: float
    sim_time_s: float
    wall_time_s: float
    path_rms_truth_m: float
    path_max_truth_m: float
    path_rms_estimate_m: float
    pad_landing_error_m: float
    pad_landing_error_ne_m: tuple[float, float]
    home_landing_error_m: float
    setpoints_sent: int
    setpoints_clamped: int
    guidance_overruns: int
    # path_*_truth_m are scored against REFERENCE; these against the mission's own path (the planned
    # one, and on the way home the one planned from the landing point), which counts the correct
    # move to a pad lying away from its configured position as error
    path_rms_planned_m: float = math.nan
    path_max_planned_m: float = math.nan
    path_reference: str = REFERENCE
    run_dir: str = ""
    events: list[tuple[float, str, str, str]] = field(default_factory=list)
    home_with_parcel: bool = False  # landed at home with the parcel aboard (docs/delivery-policy.md)
    pad_tries: int = 0  # descents onto the pad the no-release-off-the-pad policy stopped
    # |true yaw - true pad heading| at the pad touchdown (deg); NaN for a pad without a heading
    pad_heading_error_deg: float = math.nan
    # winch delivery: where the parcel first touched the ground minus the true pad centre (N, E, m);
    # NaN without a winch delivery or when the parcel never reached the ground
    parcel_touchdown_ne_m: tuple[float, float] = (math.nan, math.nan)
    failure_kind: FailureKind = FailureKind.NONE  # why it did not finish as planned (failure: the detail)

    @property
    def parcel_touchdown_error_m(self) -> float:
        return math.hypot(*self.parcel_touchdown_ne_m)

    @property
    def speedup(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.inf


@dataclass(frozen=True)
class DemoHooks:
    """How a bench instruments a demo flight's run folder without changing the flight: every
    field defaults to what a flight uses (``companion bench log``).

    - ``logs``: given to every log of the run folder (``flight.csv``, ``truth.csv``, the
      recorder's streams and ``flight.mcap``, and through the recorder the simulator's ``.tlog``):
      :class:`~companion.flightlog.hooks.LogHooks`; ``truth.csv``'s rows are queued through its
      ``write`` timed as ``"truth.csv row"``;
    - ``shell``: the delivery shell's (:class:`~companion.delivery.hooks.ShellHooks`: its stage
      ``"logging"`` wraps ``flight.csv``'s observer and the recorder's);
    - ``recorder``: the run folder's recorder class
      (:class:`~companion.flightlog.recorder.NullRecorder`: nothing logged);
    - ``csv_log``: ``flight.csv``'s and ``truth.csv``'s class
      (:class:`~companion.flightlog.csvlog.NullCsvLog`: no rows taken).
    """

    logs: LogHooks = FLIGHT
    shell: ShellHooks | None = None
    recorder: type[FlightRecorder] = FlightRecorder
    csv_log: type[CsvLog] = CsvLog


FLIGHT_HOOKS = DemoHooks()


class _Scorer:
    """Samples truth at each guidance tick while the vector field is being followed, against the
    reference of companion_sitl.scoring (the way out may end at the pad as found)."""

    FOLLOW = (Phase.OUTBOUND, Phase.INBOUND)

    def __init__(
        self,
        vehicle: SimVehicle,
        truth_log: CsvLog | None,
        true_pad_ne: tuple[float, float] | None = None,
        hooks: LogHooks = FLIGHT,
    ):
        self.vehicle = vehicle
        self.true_pad_ne = true_pad_ne  # truth frame; the reference path on the way out (path_scoring)
        self.path_scorer: PathScorer | None = None
        self.truth_log = truth_log
        self._write_truth = hooks.timed(row_stage("truth.csv"), truth_log.write) if truth_log is not None else None
        self.truth_d: list[float] = []
        self.planned_d: list[float] = []
        self.est_d: list[float] = []
        self.outbound: tuple[Any, Any, float] | None = None  # (frame, path, z_start) as first planned

    def __call__(self, shell: DeliveryShell, out: MissionOutput) -> None:
        m = shell.mission
        v = self.vehicle
        if m.frame is None or m.path is None:
            return
        off = getattr(v, "_home_offset", (0.0, 0.0, 0.0))
        # the plan lives in the autopilot's local frame, whose origin is the home estimate
        p_local_truth = np.array([v.pn - off[0], v.pe - off[1], v.pd - off[2]])
        if self.outbound is None:
            self.outbound = (m.frame, m.path, m.z_start)
        # truth in the outbound F_I throughout (the mission re-plans the way home in a frame of its own)
        p_i = self.outbound[0].point_from_ned(p_local_truth)
        d_planned = float(m.path.distance_to_path(m.frame.point_from_ned(p_local_truth)))
        if self.path_scorer is None:
            tp = self.true_pad_ne
            self.path_scorer = PathScorer((tp[0] - off[0], tp[1] - off[1]) if tp is not None else None)
        d_truth = self.path_scorer.distance(m, out.phase, p_local_truth)
        if out.phase in self.FOLLOW:
            self.truth_d.append(d_truth)
            self.planned_d.append(d_planned)
            if math.isfinite(out.lyapunov):
                self.est_d.append(math.sqrt(2.0 * out.lyapunov))
        if self._write_truth is not None:
            self._write_truth(
                (v.time_s, out.phase.value, v.pn, v.pe, v.pd, *map(float, p_i), d_truth, out.lyapunov, d_planned)
            )


def path_summary(config: SimulatedConfig, scorer: _Scorer) -> dict[str, Any]:
    """summary.json's path figures: the outbound path as planned (``path``, in its F_I), the true
    pad in that F_I and the path to the true pad that the way out is scored against."""
    if scorer.outbound is None:
        return {"path": None}
    frame, path, z_start = scorer.outbound
    out: dict[str, Any] = {
        "path": {
            "h_m": path.h,
            "r_m": path.r,
            "d_m": path.d,
            "z_start_m": z_start,
            "heading_rad": frame.heading_rad,
            "pad_ned_m": [float(x) for x in frame.pad_ned],
            "pad_size_m": config.mission.pad.size_m,
        }
    }
    ref = scorer.path_scorer.true_pad_path if scorer.path_scorer is not None else None
    if ref is not None:
        ref_frame, ref_path = ref
        out["true_pad_mission_m"] = [float(x) for x in frame.point_from_ned(ref_frame.pad_ned)]
        out["reference_path"] = {
            "pad_ned_m": [float(x) for x in ref_frame.pad_ned],
            "heading_rad": ref_frame.heading_rad,
            "d_m": ref_path.d,
        }
    return out


def true_pad_ned(config: SimulatedConfig) -> tuple[float, float]:
    """Where the pad really is in the simulator's truth frame (true home at the origin): at the
    alternate pad's place with ``sim.pad_at_alternate`` (the first pad missing)."""
    h = config.sim.home
    home = GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m)
    alternate = config.mission.alternate_pad
    if config.sim.pad_at_alternate and alternate is not None:
        pad = pad_config_ned(alternate, home)
    else:
        pad = pad_position_ned(config.mission, home)
    return float(pad[0]) + config.sim.pad_offset_m[0], float(pad[1]) + config.sim.pad_offset_m[1]


def true_pad_track(config: SimulatedConfig) -> PadTrack | None:
    """The true pad's motion over time (``[sim.pad_motion]``), None when it stands still."""
    n, e = true_pad_ned(config)
    return pad_track(config.sim.pad_motion, n, e, true_pad_heading_rad(config))


def loopback_autopilot(config: SimulatedConfig, backend: str, port: int, tlog: Any = None) -> Autopilot:
    """The ``backend``'s autopilot ("px4": MAVSDK, else pymavlink) listening on loopback UDP
    ``port`` for a MAVLink sim vehicle, with the configured link timeout and stream rates."""
    from companion.autopilot.ardupilot import ArduPilotAutopilot
    from companion.autopilot.ardupilot.requests import configured_stream_rates
    from companion.autopilot.px4 import Px4Autopilot

    rt = config.runtime
    if backend == "px4":
        px4 = Px4Autopilot(f"udpin://127.0.0.1:{port}", link_timeout_s=rt.link_timeout_s, tlog=tlog)
        px4.attitude_rate_hz, px4.position_rate_hz = rt.autopilot_attitude_rate_hz, rt.autopilot_position_rate_hz
        return px4
    rates = configured_stream_rates(rt.autopilot_attitude_rate_hz, rt.autopilot_position_rate_hz)
    return ArduPilotAutopilot(
        f"udpin:127.0.0.1:{port}", link_timeout_s=rt.link_timeout_s, tlog=tlog, stream_rates_hz=rates
    )


def _gps_only_config(config: SimulatedConfig, fusion: bool | None) -> SimulatedConfig:
    """``fusion`` = False: the parcel released where the vehicle lands (the pad-lock policy off)."""
    if fusion is False and config.landing.policy.require_pad_lock:
        policy = config.landing.policy.model_copy(update={"require_pad_lock": False})
        config = config.model_copy(update={"landing": config.landing.model_copy(update={"policy": policy})})
    return config


def _vehicle_link(
    config: SimulatedConfig, vehicle: SimVehicle, tlog: Path | None, mavlink: str | None
) -> tuple[Autopilot, SimAutopilot | None, Any]:
    """The autopilot the shell flies: the in-process SimAutopilot (also returned as such), or the
    backend over loopback MAVLink to the started sim vehicle (returned third)."""
    if mavlink is None:
        sim_ap = SimAutopilot(config.sim, vehicle, tlog_path=tlog)
        return sim_ap, sim_ap, None
    from companion.flightlog.tlog_writer import open_tlog
    from companion_sitl.mavlink.factory import mavlink_sim_vehicle

    port = free_udp_port()
    # the demo's vehicle carries a configured gripper (ArduCopter's default GRIP_ENABLE = 0 refuses it)
    grip = {"GRIP_ENABLE": 1.0} if mavlink == "ardupilot" else None
    if grip is not None and config.landing.controller == "autopilot":
        grip |= {"PLND_ENABLED": 1.0, "PLND_TYPE": 1.0}  # LAND by LANDING_TARGET, as on the real SITL
    mav_sim = mavlink_sim_vehicle(
        config.sim,
        mavlink,  # type: ignore[arg-type]
        remote=("127.0.0.1", port),
        vehicle=vehicle,
        params=grip,
    ).start()
    return loopback_autopilot(config, mavlink, port, open_tlog(tlog) if tlog is not None else None), None, mav_sim


def _open_logs(
    config: SimulatedConfig,
    run_dir: Path | None,
    sim_ap: SimAutopilot | None,
    mcap: bool = True,
    hooks: DemoHooks = FLIGHT_HOOKS,
) -> tuple[CsvLog | None, CsvLog | None, FlightRecorder | None]:
    """flight.csv, truth.csv and the per-stream recorder in ``run_dir`` (none without it); ``mcap``:
    the recorder also writes flight.mcap (with the camera frames: most of a run folder's bytes);
    ``hooks``: a bench's (:class:`DemoHooks`)."""
    if run_dir is None:
        return None, None, None
    run_dir.mkdir(parents=True, exist_ok=True)
    flight_log = hooks.csv_log(run_dir / "flight.csv", FLIGHT_LOG_COLUMNS, hooks=hooks.logs)
    truth_log = hooks.csv_log(run_dir / "truth.csv", TRUTH_COLUMNS, hooks=hooks.logs)
    # per-stream logs (events.csv included, written as they happen) for replay and reports
    recorder = hooks.recorder(run_dir, config, mcap=mcap, hooks=hooks.logs)
    if sim_ap is not None:
        sim_ap.sample_rows = recorder  # the .tlog's sample records from the recorder's rows
    return flight_log, truth_log, recorder


def _demo_result(
    config: SimulatedConfig,
    summary: Any,
    shell: DeliveryShell,
    vehicle: SimVehicle,
    scorer: _Scorer,
    wall: float,
    run_dir: Path | None,
) -> DemoResult:
    """The flight scored on truth: touchdowns at the pad and at home, the path, the shell's figures."""
    pad_n, pad_e = true_pad_ned(config)
    track = true_pad_track(config)

    def pad_at(t_s: float) -> tuple[float, float]:  # a moving pad: where it is at that instant
        return (pad_n, pad_e) if track is None else track.ne(t_s)

    # a touchdown belongs to the site it is nearest to (a mission may return without delivering)
    def near_pad(t: Any) -> bool:
        pn, pe = pad_at(t.time_s)
        return math.hypot(t.north_m - pn, t.east_m - pe) < math.hypot(t.north_m, t.east_m)

    pad_td = [t for t in vehicle.touchdowns if near_pad(t)]
    home_td = [t for t in vehicle.touchdowns if not near_pad(t)]
    pad_err_ne = (math.nan, math.nan)
    if pad_td:
        td_n, td_e = pad_at(pad_td[0].time_s)
        pad_err_ne = (pad_td[0].north_m - td_n, pad_td[0].east_m - td_e)
    home_err = math.hypot(home_td[-1].north_m, home_td[-1].east_m) if home_td else math.nan
    flight_time = (
        summary.end_time_s - summary.takeoff_time_s
        if summary.end_time_s is not None and summary.takeoff_time_s is not None
        else math.nan
    )
    return DemoResult(
        delivered=summary.delivered,
        returned=summary.returned,
        phase=shell.mission.phase.value,
        failure=summary.failure,
        failure_kind=summary.failure_kind,
        flight_time_s=flight_time,
        sim_time_s=vehicle.time_s,
        wall_time_s=wall,
        path_rms_truth_m=rms(scorer.truth_d),
        path_max_truth_m=max(scorer.truth_d) if scorer.truth_d else math.nan,
        path_rms_estimate_m=rms(scorer.est_d),
        pad_landing_error_m=math.hypot(*pad_err_ne),
        pad_landing_error_ne_m=pad_err_ne,
        home_landing_error_m=home_err,
        setpoints_sent=shell.stats.setpoints_sent,
        setpoints_clamped=shell.stats.setpoints_clamped,
        guidance_overruns=shell.stats.guidance_overruns,
        path_rms_planned_m=rms(scorer.planned_d),
        path_max_planned_m=max(scorer.planned_d) if scorer.planned_d else math.nan,
        run_dir=str(run_dir or ""),
        events=[(e.time_s, e.kind.value, e.phase.value, e.detail) for e in shell.events],
        home_with_parcel=summary.home_with_parcel,
        pad_tries=summary.pad_tries,
        pad_heading_error_deg=(
            heading_error_deg(pad_td[0].yaw_rad, true_pad_heading_rad(config))
            if pad_td and simulated_pad(config).heading_deg is not None
            else math.nan
        ),
        parcel_touchdown_ne_m=parcel_touchdown_ne(vehicle, (pad_n, pad_e)),
    )


def _write_summary(config: SimulatedConfig, run_dir: Path, result: DemoResult, scorer: _Scorer) -> None:
    """summary.json: the result without its events, plus the speed-up, the true pad and the path."""
    summary_json = {k: v for k, v in asdict(result).items() if k != "events"}
    if math.isnan(result.pad_heading_error_deg):
        del summary_json["pad_heading_error_deg"]  # a pad without a heading: as before
    if math.isnan(result.parcel_touchdown_error_m):
        del summary_json["parcel_touchdown_ne_m"]  # no winch delivery: as before
    else:
        summary_json["parcel_touchdown_error_m"] = result.parcel_touchdown_error_m
    if result.failure_kind is FailureKind.NONE:
        del summary_json["failure_kind"]  # finished as planned: as before
    else:
        summary_json["failure_kind"] = result.failure_kind.value
    summary_json["speedup"] = result.speedup
    summary_json["true_pad_ned_m"] = list(true_pad_ned(config))
    summary_json.update(path_summary(config, scorer))
    try:  # whole or not at all; a full disk keeps the flight's result (the caller prints it)
        write_text_atomic(run_dir / "summary.json", json.dumps(summary_json, indent=2, default=_json_default))
    except OSError as err:
        log.error("%s: cannot write the summary: %s (the result is printed, not saved)", run_dir, err)


async def fly(
    config: SimulatedConfig,
    run_dir: Path | None = None,
    on_tick: Callable[[DeliveryShell, MissionOutput], None] | None = None,
    timeout_s: float = 1800.0,
    telemetry: bool = False,
    mavlink: str | None = None,
    fusion: bool | None = None,
    camera_playback: CameraPlayback | None = None,
    record_camera: Path | None = None,
    mcap: bool = True,
    tlog: bool = True,
    hooks: DemoHooks = FLIGHT_HOOKS,
) -> DemoResult:
    """Fly one delivery on the simulator (on whatever loop is running) and score it.

    With ``run_dir``: the run folder; ``mcap``: with ``flight.mcap``, ``tlog``: with the link's
    ``flight.tlog``. ``hooks``: a bench's instruments of the run folder (:class:`DemoHooks`; the
    default: a flight's).

    ``camera_playback``: the landing camera is a recorded file (see :class:`CameraPlayback`);
    ``record_camera``: record the simulated camera's frames that the flight reads into this
    video and its frame-times CSV (``<video>.csv``), for playing back later.

    ``mavlink`` = "px4" or "ardupilot": the simulator is served over real MAVLink on loopback UDP
    (MavlinkSimVehicle, stepped in real time) and flown through the matching backend (MAVSDK or
    pymavlink); otherwise the in-process SimAutopilot is used.

    ``fusion`` = False flies the paper's GPS-only baseline: no landing sensors, and the parcel
    released where the vehicle lands (an explicit opt-out of the pad-lock policy).
    """
    config = _gps_only_config(config, fusion)
    vehicle = SimVehicle(config.sim)
    pad_n, pad_e = true_pad_ned(config)
    vehicle.set_pad_truth(pad_n, pad_e)
    vehicle.set_pad_track(true_pad_track(config))
    # the link traffic (MAVExplorer, QGC)
    tlog_path = run_dir / "flight.tlog" if run_dir is not None and tlog else None
    ap, sim_ap, mav_sim = _vehicle_link(config, vehicle, tlog_path, mavlink)
    use_fusion = config.landing.fusion if fusion is None else fusion
    flight_log, truth_log, recorder = _open_logs(config, run_dir, sim_ap, mcap, hooks)
    scorer = _Scorer(vehicle, truth_log, true_pad_ned(config), hooks.logs)

    def tick(shell: DeliveryShell, out: MissionOutput) -> None:
        scorer(shell, out)
        if on_tick is not None:
            on_tick(shell, out)

    kit = None
    if use_fusion:
        # over MAVLink the vehicle runs on its own thread and clock: the sensors only read its truth
        truth_src = vehicle if mav_sim is None else cast(SimVehicle, _ThreadedTruth(mav_sim))
        kit = sim_landing_kit(config, truth_src, (pad_n, pad_e), camera_playback, record_camera)
        if mav_sim is not None:
            kit = dataclasses.replace(kit, vision_in_thread=True)  # real time: keep the loop free
    shell = DeliveryShell(
        config,
        ap,
        flight_log=flight_log,
        on_tick=tick,
        telemetry=telemetry,
        landing=kit,
        recorder=recorder,
        hooks=hooks.shell,
    )
    wall0 = time.perf_counter()
    try:
        with abort_on_signals(shell):  # Ctrl-C: hold, then land, as `fly` does (docs/flying.md)
            summary = await shell.run(timeout_s=timeout_s)
    finally:
        try:
            await ap.close()
            if mav_sim is not None:
                mav_sim.stop()
        finally:
            for lg in (flight_log, truth_log, recorder):
                if lg is not None:
                    lg.close()
    wall = time.perf_counter() - wall0
    result = _demo_result(config, summary, shell, vehicle, scorer, wall, run_dir)
    if run_dir is not None:
        _write_summary(config, run_dir, result, scorer)
    return result


def parcel_touchdown_ne(vehicle: SimVehicle, pad_ne: tuple[float, float]) -> tuple[float, float]:
    """Where the winch-lowered parcel first touched the ground, minus the true pad centre (truth
    frame, m); NaN without a simulated winch or a touchdown."""
    par = vehicle.parcel
    td = par.touchdown if par is not None else None
    if td is None:
        return (math.nan, math.nan)
    return (td.north_m - pad_ne[0], td.east_m - pad_ne[1])


class _ThreadedTruth:
    """Truth of a vehicle stepped by the MAVLink sim's thread, read under its lock. The simulated
    sensors must not step it: their clock (the event loop's) is not the vehicle's."""

    def __init__(self, mav_sim: Any):
        self._sim = mav_sim

    def step_to(self, t_s: float) -> None:
        """The MAVLink sim's thread steps the vehicle in real time."""

    def _read(self, name: str) -> float:
        with self._sim.lock:
            return float(getattr(self._sim.vehicle, name))

    pn = property(lambda self: self._read("pn"))
    pe = property(lambda self: self._read("pe"))
    pd = property(lambda self: self._read("pd"))
    roll = property(lambda self: self._read("roll"))
    pitch = property(lambda self: self._read("pitch"))
    yaw = property(lambda self: self._read("yaw"))


def _json_default(o: object) -> object:
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return str(o)


def run_demo(
    config: SimulatedConfig,
    run_dir: Path | None = None,
    realtime: bool = False,
    on_tick: Callable[[DeliveryShell, MissionOutput], None] | None = None,
    telemetry: bool = False,
    mavlink: str | None = None,
    fusion: bool | None = None,
    camera_playback: CameraPlayback | None = None,
    record_camera: Path | None = None,
    mcap: bool = True,
    tlog: bool = True,
    hooks: DemoHooks = FLIGHT_HOOKS,
) -> DemoResult:
    """Fly the demo: lock-step virtual time (default), or real time (``realtime``, or always
    with ``mavlink``, whose simulator runs on the wall clock behind real sockets); the other
    arguments: :func:`fly`'s."""
    coro = fly(
        config,
        run_dir,
        on_tick,
        telemetry=telemetry,
        mavlink=mavlink,
        fusion=fusion,
        camera_playback=camera_playback,
        record_camera=record_camera,
        mcap=mcap,
        tlog=tlog,
        hooks=hooks,
    )
    if realtime or mavlink:
        return asyncio.run(coro)
    return run_virtual(coro)
