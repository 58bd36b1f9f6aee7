"""How a real ArduCopter SITL answers the payload release (no flight, no EKF wait: a few seconds
per SITL start): DO_GRIPPER is refused for good (FAILED) while GRIP_ENABLE = 0; with a servo
gripper on output 9 it is ACCEPTED and the backend confirms the release on SERVO_OUTPUT_RAW."""

from __future__ import annotations

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.interface import CommandRejected

from .conftest import GRIPPER_SERVO9, arducopter

pytestmark = pytest.mark.firmware


async def test_do_gripper_with_grip_enable_0_is_a_permanent_failure(ardupilot_root, tmp_path):
    with arducopter(ardupilot_root, tmp_path, truth=False) as (sitl, _):
        ap = ArduPilotAutopilot(sitl.connection)
        await ap.connect(timeout_s=15.0)
        try:
            with pytest.raises(CommandRejected) as exc:
                await ap.release_payload()
            assert exc.value.result == "FAILED" and exc.value.permanent, exc.value
            assert exc.value.command == "release (gripper)"
            assert not ap.telemetry.status.payload_released
        finally:
            await ap.close()


async def test_servo_gripper_release_is_confirmed_on_its_output(ardupilot_root, tmp_path):
    with arducopter(ardupilot_root, tmp_path, extra_params=GRIPPER_SERVO9, truth=False) as (sitl, _):
        ap = ArduPilotAutopilot(sitl.connection, release_servo=5)  # the wrong guess: found from SERVOn_FUNCTION
        await ap.connect(timeout_s=15.0)
        try:
            await ap.release_payload()
            assert ap.telemetry.status is not None
            assert ap.servo_outputs[8] == 1100  # GRIP_RELEASE on output 9
            assert ap.releases_unconfirmed == 0
            assert ap._status().payload_released
        finally:
            await ap.close()


async def test_servo_release_on_an_unassigned_output_is_confirmed(ardupilot_root, tmp_path):
    """DO_SET_SERVO on an output with no function is ACCEPTED and drives it (SERVO10 here)."""
    with arducopter(ardupilot_root, tmp_path, truth=False) as (sitl, _):
        ap = ArduPilotAutopilot(sitl.connection, release="servo", release_servo=10, release_pwm=1900)
        await ap.connect(timeout_s=15.0)
        try:
            await ap.release_payload()
            assert ap.servo_outputs[9] == 1900 and ap.releases_unconfirmed == 0
        finally:
            await ap.close()
