"""The delivery shell's steps before the mission flies (and the one after it), nothing armed:

- the delivery the operator planned in the GCS, downloaded from the autopilot
  (``[mission] destination = "autopilot_mission"``, docs/gcs.md);
- the autopilot's own fence uploaded and read back (``[fence] upload``, docs/go-no-go.md);
- the autopilot left (or found) disarmed in a mode it arms in, before and after the mission;
- while the mission waits in pre-flight, why the autopilot is not ready to arm, said every few s.

The pre-flight check itself (``companion fly``) is the shell's ``before_flight``, handed in.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable
from typing import Any, Protocol

from companion.autopilot.interface import Autopilot, AutopilotError
from companion.config import CompanionConfig
from companion.delivery.gonogo import GoNoGoVerdict
from companion.delivery.mission import DeliveryMission
from companion.delivery.observers import ShellObserver
from companion.scheduling import LoopClock

log = logging.getLogger(__name__)

NOT_READY_SAY_S = 5.0  # how often a pre-flight wait on an autopilot that is not ready says why


class Owner(Protocol):
    """What the steps read of the shell: its configuration and the mission they report to."""

    config: CompanionConfig
    mission: DeliveryMission


class PreflightSteps:
    def __init__(
        self, owner: Owner, autopilot: Autopilot, clock: LoopClock, watching: Callable[[], list[ShellObserver]]
    ):
        self.owner = owner
        self.autopilot = autopilot
        self.clock = clock
        self.watching = watching
        self.made_ready: list[str] = []  # what make_ready did, before the mission and after it
        self._not_ready_said_s = -math.inf

    async def autopilot_mission(self) -> tuple[CompanionConfig, str]:
        """The delivery the operator planned in the GCS (docs/gcs.md): the autopilot's mission
        downloaded, the configuration that flies to its pad and what to say of it. Nothing is armed
        yet; a mission the companion cannot fly raises
        :class:`~companion.delivery.autopilot_mission.MissionPlanError` (or MissionDownloadError)."""
        from companion.delivery.autopilot_mission import config_from_autopilot_mission

        return await config_from_autopilot_mission(self.owner.config, self.autopilot)

    async def upload_fence(self) -> None:
        """The autopilot's own fence: upload ``[fence]``, read it back and compare, before anything
        is armed; a failure refuses the delivery (docs/go-no-go.md)."""
        from companion.autopilot.fence import fence_from_config, fence_mismatch

        fence = fence_from_config(self.owner.config.fence)
        try:
            await self.autopilot.upload_fence(fence)
            why = fence_mismatch(fence, await self.autopilot.download_fence())
            if why is not None:
                raise AutopilotError(f"the fence read back differs from the one uploaded: {why}")
        except AutopilotError as err:
            log.error("fence refused: %s", err)
            self.go_no_go(GoNoGoVerdict.REFUSE, f"the autopilot's fence: {err}")
            return
        self.go_no_go(GoNoGoVerdict.GO, f"fence uploaded to the autopilot and read back: {fence.describe()}")

    def go_no_go(self, verdict: GoNoGoVerdict, detail: str) -> None:
        """A go/no-go verdict reached outside a guidance tick, to the mission (``refuse``: the
        delivery is refused; ``go``: said, nothing changes) and to the recorder, for replay."""
        now = self.clock.now()
        for ob in self.watching():
            ob.on_go_no_go(now, verdict, detail)
        if verdict is GoNoGoVerdict.REFUSE:
            self.owner.mission.refuse(now, detail)
        else:
            self.owner.mission.go_no_go(now, detail)

    async def make_ready(self, when: str) -> None:
        """Leave (or find) the autopilot disarmed in a mode it arms in, so mission after mission
        starts (:meth:`Autopilot.make_ready`); a refusal is said, not raised: the mission's own
        pre-flight wait then says why it cannot arm."""
        if type(self.autopilot).make_ready is Autopilot.make_ready:
            return  # nothing to do (the embedded simulator): not a tick of virtual time spent on it
        if not self.autopilot.link_ok and when == "after the mission":
            return
        if when == "before the mission":
            # the mode arrives with the first telemetry after connecting
            for _ in range(20):
                st = self.autopilot.telemetry.status
                if st is not None and st.mode.value != "unknown":
                    break
                await asyncio.sleep(0.1)
        else:
            await asyncio.sleep(0.5)  # the disarm's mode and armed state have arrived
        try:
            done = await asyncio.wait_for(self.autopilot.make_ready(), 10.0)
        except (AutopilotError, TimeoutError) as err:
            log.warning("%s: the autopilot's mode could not be made ready to arm: %s", when, err or "no answer")
            return
        if done:
            self.made_ready.append(f"{when}: {done}")
            log.info("%s: %s", when, done)
            from companion.autopilot.component import SEVERITY_NOTICE

            for ob in self.watching():
                ob.on_text(done, SEVERITY_NOTICE)

    def say_not_ready(self, now: float, st: Any) -> None:
        """In pre-flight, while the autopilot does not report itself ready to arm: say why every
        NOT_READY_SAY_S, with the autopilot's own words (log, and the operator's GCS)."""
        if st is None or st.healthy or now - self._not_ready_said_s < NOT_READY_SAY_S:
            return
        if self._not_ready_said_s == -math.inf:
            self._not_ready_said_s = now  # the first reports after connecting may still be settling
            return
        self._not_ready_said_s = now
        why = self.autopilot.not_ready_reason() or "no reason given"
        log.warning("waiting for the autopilot to be ready to arm: %s", why)
        from companion.autopilot.component import SEVERITY_WARNING

        for ob in self.watching():
            ob.on_text(f"not ready to arm: {why}", SEVERITY_WARNING)
