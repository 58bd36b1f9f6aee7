"""Every runtime dependency installs from a wheel on arm64 (Raspberry Pi, Jetson): tools/arm64/check.py.

Needs PyPI, so it is skipped with the reason when PyPI is unreachable, and it runs in the firmware
tier (`pytest --tier firmware`, and CI's `--tier all`), the tier of checks against what lives outside
the repository, not in the fast tier whose budget and offline runs it must not touch (docs/arm64.md).
"""

from __future__ import annotations

import importlib.util
import urllib.request
from pathlib import Path

import pytest

pytestmark = pytest.mark.firmware

CHECK = Path(__file__).resolve().parents[1] / "tools" / "arm64" / "check.py"


def _load_check():
    spec = importlib.util.spec_from_file_location("arm64_check", CHECK)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def check():
    try:
        urllib.request.urlopen("https://pypi.org/simple/pip/", timeout=10).close()
    except OSError as exc:
        pytest.skip(f"PyPI is unreachable ({exc}); the aarch64 wheel check needs it")
    return _load_check()


def test_every_runtime_dependency_has_an_aarch64_wheel(check, capsys):
    rc = check.check_wheels()
    out, err = capsys.readouterr()
    assert rc == 0, err
    for requirement in check.runtime_requirements():
        assert f"ok  {requirement}" in out
    assert "closure:" in out


def test_a_source_only_dependency_is_named(check, capsys):
    # docopt 0.6.2 ships only a source distribution: the check must fail and name it
    rc = check.check_wheels(["numpy>=1.26", "docopt==0.6.2"])
    _, err = capsys.readouterr()
    assert rc == 1
    assert "NO aarch64 wheel: docopt==0.6.2" in err
    assert "1 of 2 runtime dependencies" in err


def test_runtime_requirements_read_from_pyproject():
    reqs = _load_check().runtime_requirements()
    names = {r.split(">")[0].split("=")[0].split("[")[0].strip() for r in reqs}
    assert {"mavsdk", "eclipse-zenoh", "opencv-contrib-python-headless", "numpy", "scipy"} <= names
