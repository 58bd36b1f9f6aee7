"""Helpers for the tests against a real PX4 SITL build (skipped with the reason when absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from companion_firmware.px4_sitl import Px4NotFound, find_px4


@pytest.fixture(scope="module")
def px4_root() -> Path:
    try:
        return find_px4()
    except Px4NotFound as err:
        if os.environ.get("COMPANION_REQUIRE_FIRMWARE") == "1":  # CI with the builds shipped: absent is a failure
            pytest.fail(f"COMPANION_REQUIRE_FIRMWARE=1 but {err}")
        pytest.skip(str(err))
