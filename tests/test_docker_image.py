"""The Dockerfile's image is built and runs ``companion demo`` (tools/docker/build.py, docs/flying.md).

No Docker Hub and no docker daemon needed: the base is a Debian bookworm root made with mmdebstrap
from Debian's packages, the Dockerfile is built on it with buildah and the image run with podman.
In the firmware tier (like the arm64 wheel check it needs what lives outside the repository:
Debian's mirror, PyPI, root and those tools); skipped with the reason when any is missing or when
podman cannot run a container on this machine. A build or a demo that fails, fails.

The base root is cached under ~/.cache/companion-docker and buildah keeps the image's layers, so a
run after the first rebuilds only what changed (2 min 16 s with the pip install, 2026-12-02).
The build and the demo run at nice 10: the real SITL flights of the other worker keep the CPU.
"""

from __future__ import annotations

import importlib.util
import socket
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.firmware

BUILD = Path(__file__).resolve().parents[1] / "tools" / "docker" / "build.py"


def _load_build():
    spec = importlib.util.spec_from_file_location("docker_build", BUILD)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _reachable(host: str, port: int) -> str | None:
    try:
        socket.create_connection((host, port), timeout=10).close()
    except OSError as exc:
        return f"{host}:{port} is unreachable ({exc})"
    return None


@pytest.fixture(scope="module")
def tools():
    build = _load_build()
    arch = build.host_arch()
    try:
        build.require_host(arch)
    except build.Unavailable as err:
        pytest.skip(f"cannot build the image here: {err}")
    if not (build.cache_dir() / f"bookworm-python-{arch}.tar").exists():
        unreachable = _reachable("deb.debian.org", 80)
        if unreachable:
            pytest.skip(f"the base root is not cached and Debian's mirror {unreachable}")
    unreachable = _reachable("pypi.org", 443)
    if unreachable:
        pytest.skip(f"the image's pip install needs PyPI: {unreachable}")
    base = build.import_base(build.base_tarball(arch, refresh=False), arch)
    try:
        opts = build.run_options(base)
    except build.Unavailable as err:
        pytest.skip(str(err))
    return build, arch, opts


def test_the_image_builds_and_delivers(tools):
    """build.py builds the image and runs `companion demo` in it (podman run, the image's entry point
    and user, no network); the image runs as uid 10001 with `companion` as its entry point."""
    build, arch, _ = tools
    cmd = ["nice", "-n", "10", sys.executable, str(BUILD), "--arch", arch, "--demo"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-4000:]
    assert "DELIVERED, returned home" in r.stdout
    config = subprocess.run(
        ["podman", "image", "inspect", "--format", "{{.Config.User}} {{.Config.Entrypoint}}", build.image_tag(arch)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert config == "10001 [companion]"
