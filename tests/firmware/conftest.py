"""The real-time MAVLink fixtures of tests/autopilot (``mav``, ``udp_port``) for the firmware
harness tests, which fly the MAVLink sim vehicle the same way (conftest modules are not
importable by name under importlib mode, so the file is loaded by path)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

_spec = importlib.util.spec_from_file_location(
    "_autopilot_conftest", Path(__file__).resolve().parents[1] / "autopilot" / "conftest.py"
)
assert _spec is not None and _spec.loader is not None
_autopilot = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_autopilot)

mav = _autopilot.mav
udp_port = _autopilot.udp_port
