"""No release off the pad (docs/delivery-policy.md, docs/divert.md): the pad lock judged at the
approach height, in the descent and at touchdown; a failed try holds at the approach height,
then flies the search pattern, then tries again; after the last try the alternate pad (divert)
or home with the parcel."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from companion.config import PadLockPolicyConfig
from companion.delivery.mission.offboard import offboard_reentry
from companion.delivery.mission.states import LandingState, PadSearchState
from companion.delivery.mission.types import NOTHING, FailureKind, MissionInputs, Request, RequestKind, Step
from companion.delivery.padlock import PadLock, expanding_square, judge_pad_lock, pad_in_sight
from companion.events import EventKind, Phase
from companion.guidance.setpoint import VelocitySetpoint

if TYPE_CHECKING:
    from companion.delivery.mission.base import MissionBase
    from companion.estimation.types import StateEstimate

PAD_POSITION_GAIN_1_S = 1.0  # hold and search: speed per metre off the target (then capped)
PAD_CORNER_TOLERANCE_M = 0.5  # a search corner is reached this close
PAD_HEIGHT_TOLERANCE_M = 0.3  # the approach height is reached this close


class PadPolicy:
    def __init__(self, mission: MissionBase, policy: PadLockPolicyConfig | None):
        self.m = mission
        self.policy = policy  # None: no policy (the parcel is released wherever it lands on the way out)
        self.searched = False  # the search was flown in this try
        self.tries_before_pad = 0  # summary.pad_tries when the current pad's tries began
        self.divert_after_takeoff = ""  # touchdown without lock on the first pad: divert once airborne (the reason)
        self.divert_takeoff = False  # that take-off flies the divert's field

    # ------------------------------------------------------------------ the judgements
    def judge(self, lock: PadLock | None) -> tuple[bool, str]:
        assert self.policy is not None
        return judge_pad_lock(lock, self.policy)

    def lock_reopening(self, st: LandingState, lock: PadLock | None, time_s: float) -> bool:
        """The lock is lost only to the EKF's 1-sigma while the pad is still observed (the EKF
        re-opened its covariance after a run of gate rejections, and the next accepted observation
        closes it), for less than the policy's reopen_grace_s: a descent try is not failed on the
        tick of a re-opening (docs/delivery-policy.md)."""
        pol = self.policy
        assert pol is not None
        # the pad in sight and young enough for the lock: what is missing is the 1-sigma
        if lock is None or not pad_in_sight(lock) or lock.observation_age_s >= pol.max_observation_age_s:
            st.lock_reopened_at = None
            return False
        if st.lock_reopened_at is None:
            st.lock_reopened_at = time_s
        return time_s - st.lock_reopened_at < pol.reopen_grace_s

    def can_divert(self) -> bool:
        pol, m = self.policy, self.m
        return (
            pol is not None
            and pol.fallback == "alternate"
            and m.cfg.alternate_pad is not None
            and m.pad_index == 0
            and m.pad_ned is not None
        )

    def plan_divert(self, est: StateEstimate, reason: str) -> bool:
        """The route to the alternate pad (routes.plan_divert); its tries count from one again."""
        if not self.m.routes.plan_divert(est, reason):
            return False
        self.m.summary.diverted = True
        self.tries_before_pad = self.m.summary.pad_tries
        return True

    # ------------------------------------------------------------------ the steps
    def try_failed(self, inp: MissionInputs, reason: str) -> VelocitySetpoint | None:
        """A descent onto the pad cannot go on, or a hold and search found no lock: the policy's
        next step. Returns the setpoint of this tick (None: none)."""
        pol, m = self.policy, self.m
        assert pol is not None
        m.summary.pad_tries += 1
        n, total = m.summary.pad_tries - self.tries_before_pad, pol.descent_tries
        lock = inp.pad_lock
        if lock is None or not lock.sensors:
            m.emit(EventKind.PAD_LOCK, reason)
            self.fallback("no pad sensor: no pad lock can come", None)
            return None
        if n >= total:
            m.emit(EventKind.PAD_LOCK, f"try {n} of {total} failed: {reason}")
            where = " on the alternate pad" if m.pad_index else ""
            self.fallback(f"{total} tries without a pad lock{where}", inp.estimate)
            return None
        m.emit(
            EventKind.PAD_LOCK,
            f"try {n} of {total} failed: {reason}; holding at the approach height "
            f"({m.cfg.final_descent_alt_m} m) for up to {pol.hold_s} s",
        )
        self.searched = False
        m.goto(Phase.PAD_HOLD)
        return None

    def fallback(self, reason: str, est: StateEstimate | None) -> None:
        """The last step: divert to the alternate pad (fallback = "alternate", from the first pad, with
        an estimate), else fly home with the parcel, in the air from here (on the ground after a
        touchdown without lock: :meth:`home_with_parcel`)."""
        m = self.m
        if est is not None and self.can_divert() and self.plan_divert(est, reason):
            m.goto(Phase.DIVERT)
            return
        m.summary.fail(FailureKind.NOT_DELIVERED, f"parcel not delivered: {reason}")
        m.emit(EventKind.PAD_LOCK, f"{reason}: flying home with the parcel, to land there without releasing it")
        m.goto(Phase.INBOUND)

    def home_with_parcel(self, reason: str) -> Request | None:
        """Landed on the way out without a pad lock: nothing is released; take off and fly home
        (or to the alternate pad)."""
        m = self.m
        if not m.idle():
            return None
        if self.can_divert() and m.routes.home_geo is not None:
            self.divert_after_takeoff = reason  # planned from where it stands once armed (phases.takeoff)
            m.emit(EventKind.PAD_LOCK, f"{reason}: parcel not released; taking off to divert to the alternate pad")
            m.left_pad = True
            m.goto(Phase.ARMING)
            return m.make_request(RequestKind.ARM)
        m.summary.fail(FailureKind.NOT_DELIVERED, f"parcel not delivered: {reason}")
        m.emit(EventKind.PAD_LOCK, f"{reason}: parcel not released; taking off to fly home with it")
        m.left_pad = True  # the next ARM is for the way home
        m.goto(Phase.ARMING)
        return m.make_request(RequestKind.ARM)

    def setpoint_to(
        self, est: StateEstimate, north_m: float, east_m: float, down_m: float, speed_m_s: float
    ) -> VelocitySetpoint:
        """Hold and search: towards a point (NED), horizontally at most ``speed_m_s``, vertically at
        most the S5 descent speed."""
        m = self.m
        assert m.frame is not None
        k = PAD_POSITION_GAIN_1_S
        vn, ve = k * (north_m - est.north_m), k * (east_m - est.east_m)
        vh = math.hypot(vn, ve)
        if vh > speed_m_s:
            vn, ve = vn * speed_m_s / vh, ve * speed_m_s / vh
        vz_max = m.cfg.sector_speed_m_s[4]
        vd = min(vz_max, max(-vz_max, k * (down_m - est.down_m)))
        return VelocitySetpoint(vn, ve, vd, m.frame.yaw_to_ned(0.0))

    # ------------------------------------------------------------------ the phases
    def hold(self, inp: MissionInputs) -> Step:
        """Step 1: at the approach height over the configured pad until locked (then onto the pad
        as the lock puts it, and the descent again), for up to hold_s."""
        m, est, pol = self.m, inp.estimate, self.policy
        if est is None or m.frame is None or pol is None:
            return NOTHING
        pad = m.frame.pad_ned
        down = float(pad[2]) - m.cfg.final_descent_alt_m
        sp = self.setpoint_to(est, float(pad[0]), float(pad[1]), down, pol.search_speed_m_s)
        req = offboard_reentry(m, inp)
        if req is not None or m.state.offboard.reenter:
            return Step(sp, req)
        ok, why = judge_pad_lock(inp.pad_lock, pol)
        if ok:
            off = math.hypot(est.north_m - float(pad[0]), est.east_m - float(pad[1]))
            if off < pol.approach_tolerance_m and abs(est.down_m - down) < PAD_HEIGHT_TOLERANCE_M:
                if not m.drop_zones.may_start_descent(inp):
                    m.drop_zones.stop(inp, "at the approach height")
                    return Step(sp)
                try_n = m.summary.pad_tries - self.tries_before_pad + 1
                m.emit(
                    EventKind.PAD_LOCK,
                    f"pad locked ({why}), {off:.2f} m off it: descent try {try_n} of {pol.descent_tries}",
                )
                m.goto(Phase.LANDING_PAD)
            return Step(sp)
        if inp.time_s - m.state.t0 < pol.hold_s:
            return Step(sp)
        if pol.search_radius_m > 0.0 and not self.searched:
            self.searched = True
            pts = expanding_square(pol.search_radius_m, pol.search_spacing_m)
            m.emit(
                EventKind.PAD_LOCK,
                f"no pad lock after holding {pol.hold_s} s ({why}): searching within {pol.search_radius_m} m of the "
                f"configured pad at {pol.search_height_m} m, {len(pts)} corners at {pol.search_speed_m_s} m/s",
            )
            m.goto(Phase.PAD_SEARCH)
            m.state_as(PadSearchState).corners = [(float(pad[0]) + n, float(pad[1]) + e) for n, e in pts]
            return Step(sp)
        return Step(self.try_failed(inp, f"no pad lock after holding {pol.hold_s} s: {why}"))

    def search(self, inp: MissionInputs) -> Step:
        """Step 2: the expanding square at the search height until the pad is locked."""
        m, est, pol = self.m, inp.estimate, self.policy
        if est is None or m.frame is None or pol is None:
            return NOTHING
        st = m.state_as(PadSearchState)
        down = float(m.frame.pad_ned[2]) - pol.search_height_m
        if not st.corners:
            reason = f"search pattern flown within {pol.search_radius_m} m: pad not found"
            return Step(self.try_failed(inp, reason))
        n, e = st.corners[0]
        sp = self.setpoint_to(est, n, e, down, pol.search_speed_m_s)
        req = offboard_reentry(m, inp)
        if req is not None or st.offboard.reenter:
            return Step(sp, req)
        ok, why = judge_pad_lock(inp.pad_lock, pol)
        if ok:
            m.emit(EventKind.PAD_LOCK, f"pad found in the search ({why}): flying onto it")
            m.goto(Phase.PAD_HOLD)
            return Step(sp)
        if math.hypot(est.north_m - n, est.east_m - e) < PAD_CORNER_TOLERANCE_M and abs(est.down_m - down) < 1.0:
            if st.corner_t0 is None:
                st.corner_t0 = inp.time_s
            if inp.time_s - st.corner_t0 >= pol.search_dwell_s:
                st.corners.pop(0)
                st.corner_t0 = None
        return Step(sp)
