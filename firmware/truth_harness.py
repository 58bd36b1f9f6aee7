"""Fly the delivery against an external autopilot simulation with landing sensors rendered from
its ground truth (PX4 SITL SIH; in CI the MAVLink sim vehicle stands in for it).

The autopilot is reached through the normal backend (MAVSDK / pymavlink), exactly as in flight.
Ground truth arrives on a second MAVLink link as HIL_STATE_QUATERNION (:class:`MavlinkTruth`);
the simulated downward camera and UWB render the pad from it, the pad lying ``pad_offset_m`` away
from its configured position (SIH cannot bias GPS, so the pad moves instead: the EKF's bias state
must absorb the displacement, as delivery 5.2 describes). The landing error is scored on truth.

A moving pad (``[sim.pad_motion]``, docs/moving-pad.md): its track runs on the host's monotonic
clock (the event loop's, which the landing sensors render with), ``start_s`` counted from the
take-off (the SITL's wait for the autopilot to become ready varies). The SITL's ground cannot carry
the vehicle, so the pad stops dead at the vehicle's first ground contact on truth; the touchdown is
scored against the pad's true centre at the touchdown's instant.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from companion.autopilot.interface import Autopilot
from companion.autopilot.types import LandedState
from companion.delivery.mission import MissionOutput
from companion.delivery.planning import pad_position_ned
from companion.delivery.shell import DeliveryShell
from companion.events import EventKind, Phase
from companion.geometry.earth import GeoPoint
from companion_firmware.truth_feed import MavlinkTruth
from companion_sitl.landing_sensors import sim_landing_kit
from companion_sitl.pad_motion import PadTrack, pad_track
from companion_sitl.params import SimulatedConfig
from companion_sitl.scoring import PathScorer, heading_error_deg, rms, simulated_pad, true_pad_heading_rad
from companion_sitl.vehicle import SimVehicle

log = logging.getLogger(__name__)


#: the path's two arcs (companion.guidance.path.DeliveryPath.sector, delivery eq 1)
ARC_SECTORS = (2, 4)

#: a moving pad stops when the true vehicle comes within this of the take-off level (its ground),
#: having flown higher than AIRBORNE_M; the instant is extrapolated to height 0 from the descent rate
CONTACT_M = 0.03
AIRBORNE_M = 1.0


@dataclass(frozen=True)
class HarnessResult:
    delivered: bool
    returned: bool
    failure: str
    true_pad_ne_m: tuple[float, float]
    touchdown_truth_ne_m: tuple[float, float]
    pad_landing_error_m: float
    markers_used: int
    uwb_used: int
    landing_targets_sent: int
    fusion_outcomes: dict[str, int] = dataclasses.field(default_factory=dict)  # "sensor.outcome" -> count
    # the no-release-off-the-pad policy (docs/delivery-policy.md): landed home with the parcel
    # aboard, descents it stopped, and the mission's RELEASED events (release commands accepted)
    home_with_parcel: bool = False
    pad_tries: int = 0
    releases: int = 0
    pad_lock_events: tuple[str, ...] = ()
    drop_zone_events: tuple[str, ...] = ()
    # distance of the true vehicle to the planned path while the vector field is followed
    path_rms_truth_m: float = math.nan
    path_max_truth_m: float = math.nan
    path_rms_outbound_m: float = math.nan  # the way out only (before any pad was seen)
    path_max_outbound_m: float = math.nan
    # the largest distance to the path within its vertical plane (sideways left out) while the true
    # vehicle is in an arc (sectors 2 and 4, delivery eq 1): how far it overshoots a turn (at
    # most 0.5 m). The whole distance in the arcs also holds the move onto a displaced pad
    path_max_arcs_m: float = math.nan
    # the estimate the autopilot flies on against the mission's path: what the guidance controls
    tracking_rms_m: float = math.nan
    tracking_max_m: float = math.nan
    # the same in-plane distance in the arcs for the estimate flown on against the mission's path:
    # the overshoot the guidance controls, apart from the autopilot's own estimation error
    tracking_max_arcs_m: float = math.nan
    # a pad with a heading (docs/pad-heading.md): |true yaw - true pad heading| at the touchdown, deg
    pad_heading_error_deg: float = math.nan
    # per tick while following: time s, phase, sector of the true position, distance of truth and of
    # the estimate flown on to the path m, truth and estimate in the mission frame F_I m
    path_trace: tuple[tuple[float, str, int, float, float, tuple[float, ...], tuple[float, ...]], ...] = ()
    # at touchdown (the autopilot's first ON_GROUND in the landing): where the companion believed the
    # vehicle was from the pad (its own control error) and how far that belief was from the truth
    # (the estimation error); the landing error is at most their sum
    believed_offset_m: float = math.nan
    estimate_error_m: float = math.nan
    guidance_overruns: int = 0
    guidance_ticks: int = 0
    setpoint_overruns: int = 0
    # per tick of the descent onto the pad, until the first ON_GROUND: LANDING_TRACE_FIELDS
    landing_trace: tuple[tuple[float, ...], ...] = ()
    # a moving pad: where it was when the vehicle first touched the ground (it stands there from
    # then on), that instant and the touchdown's in s from the take-off (nan: the pad stands)
    pad_stop_ne_m: tuple[float, float] = (math.nan, math.nan)
    pad_stop_s: float = math.nan
    touchdown_s: float = math.nan
    # the true vehicle's distance from the stopped pad's centre at the contact (the touchdown's is
    # at the autopilot's landed state, seconds later: what the vehicle did on the ground between)
    contact_error_m: float = math.nan


#: a landing_trace row: time s; truth relative to the true pad (north, east m; height above the
#: take-off level m; north, east velocity m/s; roll, pitch, yaw rad); the companion's estimate
#: relative to the configured pad (north, east m; its pad-relative frame puts the pad there); the
#: setpoint (north, east, down m/s); the autopilot's own velocity (north, east m/s) and attitude
#: (roll, pitch, yaw rad); its landed state (LandedState value; nan: none yet)
LANDING_TRACE_FIELDS = (
    "t_s", "truth_n_m", "truth_e_m", "truth_h_m", "truth_vn_m_s", "truth_ve_m_s",
    "truth_roll_rad", "truth_pitch_rad", "truth_yaw_rad", "est_n_m", "est_e_m",
    "sp_vn_m_s", "sp_ve_m_s", "sp_vd_m_s", "ap_vn_m_s", "ap_ve_m_s",
    "ap_roll_rad", "ap_pitch_rad", "ap_yaw_rad", "landed", "ap_t_s", "ap_n_m", "ap_e_m",
)  # fmt: skip


def true_pad_ne(config: SimulatedConfig, origin: GeoPoint, pad_offset_m: tuple[float, float]) -> tuple[float, float]:
    """The pad's true position in the truth frame: configured (from the true home) + displacement."""
    p = pad_position_ned(config.mission, origin)
    return float(p[0]) + pad_offset_m[0], float(p[1]) + pad_offset_m[1]


class _TruthScore:
    """The shell's ``on_tick``: the true vehicle against the mission's path while it follows it,
    the descent onto the pad, and the touchdown, all scored on ``truth``."""

    def __init__(self, truth: MavlinkTruth, pad_ne: tuple[float, float], track: PadTrack | None = None) -> None:
        self.truth = truth
        self.pad_ne = pad_ne  # the standing pad (the path is scored against it)
        self.track = track  # a moving pad: its clock starts at the take-off, it stops at the contact
        self.pad_touchdown: tuple[float, float] | None = None  # the pad's centre at the touchdown
        self.touchdown_t: float | None = None
        self._airborne = False
        self._contact_guess: tuple[float, float, float] | None = None  # the last sinking tick's (time, height, sink)
        self._ref_before: tuple[float, float, float] | None = None  # the sinking tick before it
        self.contact_ne: tuple[float, float] | None = None  # the true vehicle when the pad stopped
        self.touchdown: list[tuple[float, float]] = []
        self.touchdown_yaw: list[float] = []
        self.believed: list[tuple[float, float]] = []  # estimate - configured pad at touchdown, NE m
        self.path_d: list[float] = []
        self.path_out: list[float] = []
        self.arcs_in_plane: list[float] = []
        self.arcs_tracking: list[float] = []
        self.trace: list[tuple[float, str, int, float, float, tuple[float, ...], tuple[float, ...]]] = []
        self.landing_trace: list[tuple[float, ...]] = []
        self.t_start = time.monotonic()
        self.scorer: PathScorer | None = None
        # truth <-> the autopilot's local frame, fixed at the start (home, on the ground): the
        # autopilot may move home later (PX4 sets it again when it re-arms on the pad)
        self.ref: list[tuple[tuple[float, float, float], tuple[float, float, float]]] = []
        self.t_ground = truth.pd  # the take-off level (SIH's ground; the vehicle starts on it)

    def __call__(self, shell: DeliveryShell, out: MissionOutput) -> None:
        truth = self.truth
        home = shell.autopilot.telemetry.home
        if not self.ref and home is not None and truth.age_s < 1.0:
            self.ref.append(((truth.pn, truth.pe, truth.pd), (home.north_m, home.east_m, home.down_m)))
        if self.track is not None:
            self._move_pad(out.phase)
        m = shell.mission
        following = out.phase in (Phase.OUTBOUND, Phase.INBOUND) and m.frame is not None and m.path is not None
        if following and self.ref and truth.age_s < 1.0:
            self._follow(shell, out)
        self._landing(shell, out)

    def _follow(self, shell: DeliveryShell, out: MissionOutput) -> None:
        m = shell.mission
        assert m.frame is not None and m.path is not None
        t0, h0 = self.ref[0]
        p = [getattr(self.truth, a) - s0 + hh for a, s0, hh in zip(("pn", "pe", "pd"), t0, h0, strict=True)]
        if not all(math.isfinite(x) for x in p):
            return
        if self.scorer is None:
            # the true pad in the autopilot's local frame, through the same fixed mapping
            self.scorer = PathScorer((self.pad_ne[0] - t0[0] + h0[0], self.pad_ne[1] - t0[1] + h0[1]))
        self.path_d.append(self.scorer.distance(m, out.phase, p))
        p_i = m.frame.point_from_ned(np.array(p))
        est = shell.estimate
        e_i = m.frame.point_from_ned(est.position_ned) if est is not None else np.full(3, math.nan)
        self.trace.append(
            (
                time.monotonic() - self.t_start,
                out.phase.value,
                int(m.path.sector(p_i)),
                self.path_d[-1],
                float(m.path.distance_to_path(e_i)),
                tuple(float(x) for x in p_i),
                tuple(float(x) for x in e_i),
            )
        )
        if out.phase is Phase.OUTBOUND:
            self.path_out.append(self.path_d[-1])
        if self.trace[-1][2] in ARC_SECTORS:
            self.arcs_in_plane.append(self.scorer.in_plane_distance(m, out.phase, p))
            self.arcs_tracking.append(float(m.path.distance_in_plane(e_i)))

    def pad_at(self, t_s: float) -> tuple[float, float]:
        """The true pad's centre at clock time ``t_s``."""
        return self.pad_ne if self.track is None else self.track.ne(t_s)

    def _move_pad(self, phase: Phase) -> None:
        """The moving pad's clock starts with the take-off; the pad stops at the first contact."""
        truth, tr = self.truth, self.track
        assert tr is not None
        now = time.monotonic()
        if tr.origin_s is None and phase not in (Phase.PREFLIGHT, Phase.ARMING):
            tr.start_clock(now)
            log.info("moving pad: its clock starts at the take-off (start_s = %.1f s from here)", tr.config.start_s)
        if tr.origin_s is None or tr.stopped_s is not None or truth.age_s >= 1.0:
            return
        h, vd, t_sample = self.t_ground - truth.pd, truth.vd, now - truth.age_s
        if h > AIRBORNE_M:
            self._airborne = True
        ref = self._contact_guess  # the last tick that was sinking at its reported rate
        sink_h = (ref[1] - h) / (t_sample - ref[0]) if ref is not None and t_sample > ref[0] else math.nan
        if vd >= 0.2 and (ref is None or h > CONTACT_M or not sink_h < 0.5 * vd):
            self._contact_guess, self._ref_before = (t_sample, h, vd), ref
        elif vd < 0.2 and h > CONTACT_M:
            self._contact_guess = self._ref_before = None  # not descending: no reference
        if not self._airborne or ref is None or h > CONTACT_M or not t_sample > ref[0]:
            return
        # the instant from the tick before the last that sank: the last may have been on the
        # ground already (its height already the ground's: it looked like a sink)
        t0, h0, vd0 = self._ref_before or ref
        # the descent stopped near the ground (a SITL's ground stops the vehicle dead; PX4 SIH's lies
        # a few cm below the take-off level): by the reported sink or by the height (ArduCopter's
        # SIM_STATE), against the last tick that sank; the instant where that sink met this height
        if not (vd < 0.25 * vd0 or sink_h < 0.25 * vd0):
            return
        t_c = min(max(t0 + (h0 - h) / vd0, t0), t_sample)
        tr.stop_at(t_c)
        n, e = tr.ne(t_c)
        self.contact_ne = (truth.pn, truth.pe)  # stopped dead there by the SITL's ground
        log.info(
            "moving pad: ground contact at %.2f s from the take-off (height %.3f m, %.2f m/s down): the pad stops "
            "at %.2f, %.2f m",
            t_c - (tr.origin_s or 0.0),
            h,
            vd,
            n,
            e,
        )

    def _landing(self, shell: DeliveryShell, out: MissionOutput) -> None:
        truth = self.truth
        st = shell.autopilot.telemetry.status
        if not self.touchdown and out.phase is Phase.LANDING_PAD and truth.age_s < 1.0:
            pad_now = self.pad_at(time.monotonic())
            row = _landing_row(time.monotonic() - self.t_start, shell, out, truth, pad_now, self.t_ground)
            self.landing_trace.append(row)
        # the autopilot's landed state on the descent, or the mission's own touchdown on the pad
        # (with few status messages, as on a 115200 baud line, it can decide on the tick the
        # landed state arrives and leave LANDING_PAD on it)
        on_ground = out.phase is Phase.LANDING_PAD and st is not None and st.landed is LandedState.ON_GROUND
        decided = shell.mission.summary.pad_touchdown_ned is not None
        if not self.touchdown and (on_ground or decided) and truth.age_s < 1.0:
            self.touchdown.append((truth.pn, truth.pe))
            self.touchdown_yaw.append(truth.yaw)
            self.touchdown_t = time.monotonic()
            self.pad_touchdown = self.pad_at(self.touchdown_t)
            est, pad_cfg = shell.estimate, shell.mission.pad_ned
            if est is not None and pad_cfg is not None:
                self.believed.append((float(est.position_ned[0] - pad_cfg[0]), float(est.position_ned[1] - pad_cfg[1])))


def _harness_result(config: SimulatedConfig, summary: Any, shell: DeliveryShell, sc: _TruthScore) -> HarnessResult:
    # the pad's centre at the touchdown's instant (a moving pad stands where it stopped)
    pad_ne = sc.pad_touchdown if sc.pad_touchdown is not None else sc.pad_at(time.monotonic())
    td = sc.touchdown[0] if sc.touchdown else (math.nan, math.nan)
    tr = sc.track
    origin = tr.origin_s if tr is not None and tr.origin_s is not None else math.nan
    stop = tr.stopped_s if tr is not None and tr.stopped_s is not None else math.nan
    err = math.hypot(td[0] - pad_ne[0], td[1] - pad_ne[1])
    # both offsets from the pad are frame-free (the truth and autopilot frames differ by a shift)
    b = sc.believed[0] if sc.believed else (math.nan, math.nan)
    est_err = math.hypot(b[0] - (td[0] - pad_ne[0]), b[1] - (td[1] - pad_ne[1]))
    fusion: Any = shell.fusion
    return HarnessResult(
        delivered=summary.delivered,
        returned=summary.returned,
        failure=summary.failure,
        true_pad_ne_m=pad_ne,
        touchdown_truth_ne_m=td,
        pad_landing_error_m=err,
        markers_used=fusion.counters.markers_used if fusion is not None else 0,
        uwb_used=fusion.counters.uwb_used if fusion is not None else 0,
        landing_targets_sent=shell.landing_targets_sent,
        fusion_outcomes=dict(fusion.counters.outcomes) if fusion is not None else {},
        path_rms_truth_m=rms(sc.path_d),
        path_max_truth_m=max(sc.path_d) if sc.path_d else math.nan,
        path_rms_outbound_m=rms(sc.path_out),
        path_max_outbound_m=max(sc.path_out) if sc.path_out else math.nan,
        path_max_arcs_m=max(sc.arcs_in_plane, default=math.nan),
        tracking_rms_m=rms([row[4] for row in sc.trace]),
        tracking_max_m=max((row[4] for row in sc.trace), default=math.nan),
        tracking_max_arcs_m=max(sc.arcs_tracking, default=math.nan),
        path_trace=tuple(sc.trace),
        believed_offset_m=math.hypot(*b),
        estimate_error_m=est_err,
        guidance_overruns=shell.stats.guidance_overruns,
        guidance_ticks=shell.stats.guidance_ticks,
        setpoint_overruns=shell.stats.setpoint_overruns,
        landing_trace=tuple(sc.landing_trace),
        home_with_parcel=summary.home_with_parcel,
        pad_tries=summary.pad_tries,
        releases=sum(e.kind is EventKind.RELEASED for e in summary.events),
        pad_lock_events=tuple(e.detail for e in summary.events if e.kind is EventKind.PAD_LOCK),
        drop_zone_events=tuple(e.detail for e in summary.events if e.kind is EventKind.DROP_ZONE),
        pad_stop_ne_m=tr.ne(stop) if tr is not None and math.isfinite(stop) else (math.nan, math.nan),
        pad_stop_s=stop - origin,
        contact_error_m=(
            math.hypot(sc.contact_ne[0] - pad_ne[0], sc.contact_ne[1] - pad_ne[1])
            if sc.contact_ne is not None
            else math.nan
        ),
        touchdown_s=(sc.touchdown_t if sc.touchdown_t is not None else math.nan) - origin,
        pad_heading_error_deg=(
            heading_error_deg(sc.touchdown_yaw[0], true_pad_heading_rad(config))
            if sc.touchdown_yaw and simulated_pad(config).heading_deg is not None
            else math.nan
        ),
    )


async def fly_on_truth(
    config: SimulatedConfig,
    autopilot: Autopilot,
    truth: MavlinkTruth,
    origin: GeoPoint,
    pad_offset_m: tuple[float, float],
    timeout_s: float = 300.0,
    recorder: Any | None = None,
    pad_ne: tuple[float, float] | None = None,
    on_shell: Any | None = None,
    parcel_at: Any | None = None,
) -> HarnessResult:
    """One delivery (with the landing sensors rendered from ``truth`` when ``landing.fusion``);
    ``truth`` must be started (and is not stopped here). ``pad_ne``
    gives the true pad in the truth frame directly (a vehicle that does not start at the truth
    origin); otherwise it is the configured pad from ``origin`` plus ``pad_offset_m``. ``on_shell``
    (a function of the shell) is called with the shell before it runs (a lab script's instruments).
    ``parcel_at``: where the parcel on the firmware's winch line is, for the camera to draw it
    (truth_parcel.ParcelOnTruth.bottom_ned, with ``[sim.winch] draw_parcel``)."""
    if pad_ne is None:
        pad_ne = true_pad_ne(config, origin, pad_offset_m)
    kit = None
    track = pad_track(config.sim.pad_motion, pad_ne[0], pad_ne[1], true_pad_heading_rad(config))
    if track is not None:
        track.start_clock(None)  # the pad stands until the take-off (_TruthScore)
    if config.landing.fusion:  # a GPS-only flight has no landing sensors: it fuses nothing
        kit = sim_landing_kit(config, cast(SimVehicle, truth), pad_ne, track=track, parcel_at=parcel_at)
        kit = dataclasses.replace(kit, vision_in_thread=True)  # real time: keep the loop free
    score = _TruthScore(truth, pad_ne, track)
    shell = DeliveryShell(config, autopilot, on_tick=score, landing=kit, recorder=recorder)
    if on_shell is not None:
        on_shell(shell)
    summary = await shell.run(timeout_s=timeout_s)
    return _harness_result(config, summary, shell, score)


def _landing_row(
    t_s: float,
    shell: DeliveryShell,
    out: MissionOutput,
    truth: MavlinkTruth,
    pad_ne: tuple[float, float],
    ground_d: float,
) -> tuple[float, ...]:
    """One LANDING_TRACE_FIELDS row."""
    nan = math.nan
    est, pad_cfg = shell.estimate, shell.mission.pad_ned
    en, ee = (
        (float(est.position_ned[0] - pad_cfg[0]), float(est.position_ned[1] - pad_cfg[1]))
        if est is not None and pad_cfg is not None
        else (nan, nan)
    )
    sp = out.setpoint
    tel = shell.autopilot.telemetry
    pos, att, st = tel.position_ned, tel.attitude, tel.status
    return (
        t_s,
        truth.pn - pad_ne[0],
        truth.pe - pad_ne[1],
        ground_d - truth.pd,
        truth.vn,
        truth.ve,
        truth.roll,
        truth.pitch,
        truth.yaw,
        en,
        ee,
        *((sp.north_m_s, sp.east_m_s, sp.down_m_s) if sp is not None else (nan, nan, nan)),
        *((pos.north_m_s, pos.east_m_s) if pos is not None else (nan, nan)),
        *((att.roll_rad, att.pitch_rad, att.yaw_rad) if att is not None else (nan, nan, nan)),
        (1.0 if st.landed is LandedState.ON_GROUND else 0.0) if st is not None else nan,
        *((pos.time_s, pos.north_m, pos.east_m) if pos is not None else (nan, nan, nan)),
    )


def flight_story(run_dir: Path, firmware_log: Path | None = None, tail_lines: int = 30) -> str:
    """What a failed SITL flight leaves for its reader, as text: the mission's events and the
    requests with their results (events.csv, requests.csv), every change of the autopilot's mode,
    arming or landed state (ap_status.csv), its STATUSTEXTs, and the end of the firmware's own log.
    A file that is missing or unreadable is named, never fatal (this runs after a failure); the
    streams are read as replay reads them (:func:`~companion.flightlog.reader.open_table`: a torn
    last line dropped, ``flight.mcap`` standing in for a missing CSV)."""
    from companion.flightlog.reader import LogFormatError, open_table

    out: list[str] = []

    def rows(name: str) -> list[dict[str, str]] | None:
        try:
            table = open_table(run_dir, name)
        except LogFormatError as err:
            out.append(f"{name}: not readable ({err})")
            return None
        return [dict(zip(table.header, r, strict=True)) for r in table.rows]

    def t(row: dict[str, str]) -> str:
        return row.get("time_s", "?")[:10]

    events = rows("events.csv")
    if events is not None:
        out.append(f"events.csv ({len(events)}):")
        out += [f"  {t(r)} {r.get('phase')} {r.get('kind')} {r.get('detail')}" for r in events]
    requests = rows("requests.csv")
    if requests is not None:
        out.append(f"requests.csv ({len(requests)}):")
        out += [
            f"  {t(r)} #{r.get('id')} {r.get('kind')} {'ok' if r.get('ok') == '1' else 'FAILED ' + str(r.get('error'))}"
            for r in requests
        ]
    status = rows("ap_status.csv")
    if status is not None:
        changes: list[str] = []
        last: tuple[str | None, ...] = ()
        for r in status:
            now = (r.get("armed"), r.get("mode"), r.get("landed"), r.get("healthy"))
            if now != last:
                changes.append(f"  {t(r)} armed={now[0]} mode={now[1]} landed={now[2]} healthy={now[3]}")
                last = now
        tail = f", last at {t(status[-1])}" if status else ""
        out.append(f"ap_status.csv ({len(status)} rows{tail}), changes:")
        out += changes
    position = rows("ap_position.csv")
    if position:
        p = position[-1]
        out.append(f"ap_position.csv ({len(position)} rows): last at {t(p)}, down {p.get('down_m')} m")
    texts = rows("ap_statustext.csv")
    if texts is not None:
        out.append(f"ap_statustext.csv ({len(texts)}):")
        out += [f"  {t(r)} [{r.get('severity')}] {r.get('text')}" for r in texts]
    if firmware_log is not None:
        try:
            lines = firmware_log.read_text(errors="replace").splitlines()
        except OSError as err:
            out.append(f"{firmware_log.name}: not readable ({err})")
        else:
            out.append(f"{firmware_log.name}, last {min(tail_lines, len(lines))} of {len(lines)} lines:")
            out += [f"  {line}" for line in lines[-tail_lines:]]
    return "\n".join(out)
