"""A refused command's outcome as a type (CommandResult): the backends' names parsed once, where
the refusal is made; permanence and the arm retry decide on the kind, the message keeps the name."""

from __future__ import annotations

import pytest

from companion.autopilot.ardupilot.autopilot import ARM_RETRY_RESULTS
from companion.autopilot.interface import PERMANENT_RESULTS, CommandRejected, CommandResult


@pytest.mark.parametrize(
    ("result", "kind", "permanent"),
    [
        ("DENIED", CommandResult.DENIED, True),
        ("TEMPORARILY_REJECTED", CommandResult.TEMPORARILY_REJECTED, False),
        (CommandResult.NO_ANSWER, CommandResult.NO_ANSWER, True),
        (CommandResult.LOST, CommandResult.LOST, False),  # silence on a lossy link: sent again
        ("LINK_DOWN", CommandResult.LINK_DOWN, False),
        ("MAV_RESULT 42", CommandResult.OTHER, False),  # a number beyond common.xml
        ("denied", CommandResult.OTHER, False),  # names are exact: no guessing from text
    ],
)
def test_the_kind_is_parsed_once_and_decides(result, kind, permanent):
    err = CommandRejected("arm", result, "Arm: Need Position Estimate")
    assert err.kind is kind and err.permanent is permanent
    name = result.value if isinstance(result, CommandResult) else result
    assert err.result == name and str(err) == f"arm: {name} (Arm: Need Position Estimate)"


def test_the_sets_that_decide_hold_kinds():
    assert all(isinstance(k, CommandResult) for k in PERMANENT_RESULTS | ARM_RETRY_RESULTS)
