"""Never release onto an occupied pad (docs/drop-zone.md): the drop-zone check's
verdict (companion.vision.drop_zone, ``MissionInputs.drop_zone``) judged at the approach height,
in the final descent above the commit height and at touchdown. The final descent starts only on a
pad judged clear; an object on the pad or motion in its margin stops it: the vehicle holds where
it is (phase ``drop_zone_hold``) for ``landing.drop_zone.hold_s``; the pad cleared, it flies the
pad-lock policy's hold onto the pad and descends again; still not clear, it diverts to the
alternate pad if configured, else flies home with the parcel (``PadPolicy.fallback``). A
touchdown on a pad judged occupied releases nothing (``PadPolicy.home_with_parcel``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from companion.config import DropZoneConfig
from companion.delivery.mission.offboard import offboard_reentry
from companion.delivery.mission.states import DropZoneHoldState
from companion.delivery.mission.types import NOTHING, MissionInputs, Step
from companion.events import EventKind, Phase
from companion.vision.drop_zone import DropZoneVerdict

if TYPE_CHECKING:
    from companion.delivery.mission.base import MissionBase

#: the verdicts that stop a descent
BLOCKING = (DropZoneVerdict.OCCUPIED, DropZoneVerdict.MOTION_IN_MARGIN)
#: the hold flies back to where it began at most this fast (m/s)
HOLD_SPEED_M_S = 1.0
WHAT = {
    DropZoneVerdict.OCCUPIED: "an object on the pad",
    DropZoneVerdict.MOTION_IN_MARGIN: "motion in the pad's margin",
    DropZoneVerdict.UNKNOWN: "the drop zone not judged clear yet",
}


class DropZonePolicy:
    """The mission's answer to the drop-zone verdict; ``config`` None (or not enabled): no check,
    every judgement passes."""

    def __init__(self, mission: MissionBase, config: DropZoneConfig | None):
        self.m = mission
        self.config = config if config is not None and config.enabled else None

    def blocked(self, inp: MissionInputs) -> bool:
        """The verdict forbids descending or releasing now."""
        return self.config is not None and inp.drop_zone in BLOCKING

    def may_start_descent(self, inp: MissionInputs) -> bool:
        """The final descent starts on a pad seen clear (an unknown verdict: the camera has not
        judged it, which is no evidence that nothing is there)."""
        return self.config is None or inp.drop_zone is DropZoneVerdict.CLEAR

    def stop(self, inp: MissionInputs, where: str) -> None:
        """Stop the descent ``where`` it is and hold (phase drop_zone_hold)."""
        m, cfg = self.m, self.config
        assert cfg is not None
        verdict = inp.drop_zone if inp.drop_zone is not None else DropZoneVerdict.UNKNOWN
        m.emit(
            EventKind.DROP_ZONE,
            f"{WHAT[verdict]} {where}: descent stopped, holding for up to {cfg.hold_s:g} s",
        )
        m.goto(Phase.DROP_ZONE_HOLD)
        st = m.state_as(DropZoneHoldState)
        st.why = verdict.value
        if inp.estimate is not None:
            st.hold_ned = inp.estimate.position_ned

    def hold(self, inp: MissionInputs) -> Step:
        """Phase drop_zone_hold: where the descent stopped, until the zone is clear or hold_s."""
        m, est, cfg = self.m, inp.estimate, self.config
        if est is None or cfg is None or m.frame is None:
            return NOTHING
        st = m.state_as(DropZoneHoldState)
        if st.hold_ned is None:
            st.hold_ned = est.position_ned
        n, e, d = st.hold_ned
        sp = m.pads.setpoint_to(est, n, e, d, HOLD_SPEED_M_S)
        req = offboard_reentry(m, inp)
        if req is not None or st.offboard.reenter:
            return Step(sp, req)
        held_s = inp.time_s - st.t0
        if inp.drop_zone is DropZoneVerdict.CLEAR:
            m.emit(EventKind.DROP_ZONE, f"drop zone clear after holding {held_s:.1f} s: descending again")
            m.goto(Phase.PAD_HOLD if m.pad_policy is not None else Phase.LANDING_PAD)
            return Step(sp)
        if held_s < cfg.hold_s:
            return Step(sp)
        now = inp.drop_zone.value if inp.drop_zone is not None else "no verdict"
        reason = f"drop zone not clear after holding {cfg.hold_s:g} s ({now})"
        m.emit(EventKind.DROP_ZONE, reason)
        m.pads.fallback(reason, est)
        return Step(sp)
