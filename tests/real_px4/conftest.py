"""Helpers for the tests against a real PX4 SITL build (skipped with the reason when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion_firmware.px4_sitl import Px4NotFound, find_px4


@pytest.fixture(scope="module")
def px4_root() -> Path:
    try:
        return find_px4()
    except Px4NotFound as err:
        pytest.skip(str(err))
