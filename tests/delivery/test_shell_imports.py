"""Nothing the flight needs is imported during the flight: the modules the landing fusion starts
with at take-off are loaded with the shell (docs/cpu-budget.md: an import in the loop's thread
stalled guidance at a Pi-sized CPU budget)."""

from __future__ import annotations

import json
import subprocess
import sys

FLIGHT_MODULES = (
    "companion.delivery.fusion",
    "companion.delivery.pad_tilt",
    "companion.geometry.level",
    "companion.geometry.mounts",
    "companion.uwb.multilateration",
)


def test_the_landing_fusion_is_loaded_with_the_shell():
    code = (
        "import json, sys; import companion.delivery.shell; "
        f"print(json.dumps([m for m in {list(FLIGHT_MODULES)!r} if m not in sys.modules]))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert json.loads(out.stdout) == []


def test_the_shell_does_not_load_scipy_spatial():
    """Two closed forms (geometry.rotations) replaced its Rotation: 9 MiB and ~0.15 s of import."""
    code = "import sys; import companion.delivery.shell; print(any(m.startswith('scipy.spatial') for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == "False"


def test_starting_the_fusion_imports_nothing_new():
    """start_fusion and uwb_step name no module of their own (a lazy import there is what this guards)."""
    import inspect

    from companion.delivery.landing_sensing import LandingSensing

    for method in (LandingSensing.start_fusion, LandingSensing.follow_pad, LandingSensing.uwb_step):
        src = inspect.getsource(method)
        assert "import " not in src, method.__name__
