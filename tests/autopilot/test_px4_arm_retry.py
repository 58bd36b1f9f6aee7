"""Px4Autopilot's arm asks again while PX4 denies it for a failing health or pre-flight check (a
sensor that timed out for a moment), until its arm_timeout_s; any other denial is passed on at once."""

import pytest
from mavsdk.plugins.action import ActionError, ActionResult

from companion.autopilot.interface import CommandRejected
from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.px4 import autopilot as px4_autopilot
from companion.autopilot.px4.autopilot import is_check_refusal
from companion.autopilot.types import FlightMode

HEALTH_DENIAL = "Arming denied: Resolve system health failures first"


class Action:
    """MAVSDK's Action plugin as far as arm() goes; each denial comes with PX4's STATUSTEXT."""

    def __init__(self, ap: Px4Autopilot, denials: list[str]) -> None:
        self.ap, self.denials, self.calls = ap, denials, 0

    async def arm(self) -> None:
        self.calls += 1
        if self.denials:
            self.ap._last_text = self.denials.pop(0)  # on_text: the reason follows the ack
            self.ap._texts_seen += 1
            raise ActionError(ActionResult.COMMAND_DENIED, "arm()")
        self.ap._armed = True


def _autopilot(denials: list[str], healthy: bool = True, arm_timeout_s: float = 10.0) -> tuple[Px4Autopilot, Action]:
    ap = Px4Autopilot("udpin://127.0.0.1:14599", arm_timeout_s=arm_timeout_s)
    ap._system = object()
    ap._connected, ap._last_rx = True, float("inf")  # link_ok without a link
    ap._mode = FlightMode.HOLD  # no mode switch first
    ap._healthy = healthy
    action = ap._action = Action(ap, denials)
    return ap, action


@pytest.fixture(autouse=True)
def fast_retries(monkeypatch):
    monkeypatch.setattr(px4_autopilot, "ARM_RETRY_S", 0.001)


async def test_a_health_denial_is_asked_again_until_the_vehicle_arms(monkeypatch):
    ap, action = _autopilot(["Preflight Fail: No valid data from Baro 0", HEALTH_DENIAL])
    assert ap.link_ok
    await ap.arm()
    assert ap._armed and action.calls == 3


async def test_a_denial_while_px4_reports_itself_not_armable_is_asked_again():
    ap, action = _autopilot(["Arming denied: some check"], healthy=False)
    await ap.arm()
    assert ap._armed and action.calls == 2


async def test_a_mode_denial_on_a_healthy_vehicle_is_passed_on_at_once():
    ap, action = _autopilot(["Arming denied: switch to a manual mode"])
    with pytest.raises(CommandRejected) as err:
        await ap.arm()
    assert err.value.result == "DENIED" and err.value.permanent and "manual mode" in err.value.reason
    assert action.calls == 1


async def test_a_health_denial_that_lasts_ends_at_arm_timeout_with_px4s_answer(monkeypatch):
    ap, action = _autopilot([HEALTH_DENIAL] * 10**6, arm_timeout_s=0.3)  # each try waits 0.05 s for the text
    with pytest.raises(CommandRejected) as err:
        await ap.arm()
    assert err.value.result == "DENIED" and err.value.reason == HEALTH_DENIAL
    assert 3 < action.calls < 10**6


def test_px4s_answer_is_kept_as_its_mav_result():
    """MAVSDK's result enum and the COMMAND_ACK's number both become a :class:`MavResult` (the
    refusal's ``result`` stays its name); the arm retry decides on it, the text only says which
    check failed."""
    from companion.autopilot.interface import LINK_DOWN, NO_ANSWER
    from companion.autopilot.px4.requests import MavResult, Px4CommandRejected

    denied = Px4CommandRejected("arm", MavResult.DENIED, HEALTH_DENIAL)
    assert denied.result == "DENIED" and denied.mav_result is MavResult.DENIED and denied.permanent
    assert str(denied) == f"arm: DENIED ({HEALTH_DENIAL})"
    assert is_check_refusal(denied, healthy=True)
    assert is_check_refusal(Px4CommandRejected("arm", MavResult.TEMPORARILY_REJECTED, HEALTH_DENIAL), healthy=True)
    for other in (MavResult.FAILED, MavResult.UNSUPPORTED, NO_ANSWER, LINK_DOWN):
        err = Px4CommandRejected("arm", other, HEALTH_DENIAL)
        assert not is_check_refusal(err, healthy=True), other
        assert err.mav_result is (other if isinstance(other, MavResult) else None)
    # another backend's refusal carries no MAV_RESULT of PX4's: not a check to wait for
    assert not is_check_refusal(CommandRejected("arm", "DENIED", HEALTH_DENIAL), healthy=True)


async def test_mavsdks_result_enum_becomes_the_mav_result():
    from companion.autopilot.px4.requests import MavResult

    ap, _ = _autopilot([])

    async def busy() -> None:
        raise ActionError(ActionResult.BUSY, "arm()")

    async def timeout() -> None:
        raise ActionError(ActionResult.TIMEOUT, "arm()")

    with pytest.raises(CommandRejected) as err:
        await ap._call("arm", busy)
    assert err.value.mav_result is MavResult.TEMPORARILY_REJECTED and err.value.result == "TEMPORARILY_REJECTED"
    with pytest.raises(CommandRejected) as err:
        await ap._call("arm", timeout)
    assert err.value.mav_result is None and err.value.result == "NO_ANSWER"


async def test_a_command_acks_result_becomes_the_mav_result(monkeypatch):
    from companion.autopilot.px4.requests import MavResult

    ap, _ = _autopilot([])

    class Ack:
        def __init__(self, result: int) -> None:
            self.fields_json = f'{{"result": {result}}}'

    for number, want in ((2, MavResult.DENIED), (1, MavResult.TEMPORARILY_REJECTED), (4, MavResult.FAILED)):

        async def answered(name, fn, number=number):  # type: ignore[no-untyped-def]
            return Ack(number)

        monkeypatch.setattr(ap, "_call", answered)
        with pytest.raises(CommandRejected) as err:
            await ap._direct_command("arm (switch to HOLD first)", 176, 1, 4, 3)
        assert err.value.mav_result is want and err.value.result == want.name
    monkeypatch.setattr(ap, "_call", lambda name, fn: _answer(Ack(99)))
    with pytest.raises(CommandRejected) as err:
        await ap._direct_command("arm (switch to HOLD first)", 176, 1, 4, 3)
    assert err.value.mav_result is None and err.value.result == "99"


async def _answer(value):  # type: ignore[no-untyped-def]
    return value
