#!/usr/bin/env python3
"""arm64 (aarch64) support, checked two ways (docs/arm64.md).

``wheels``: every runtime dependency in pyproject.toml has a binary wheel for Linux aarch64 and
CPython 3.11, and so does the whole dependency closure; nothing would have to be compiled on a
Raspberry Pi or a Jetson. pip resolves against PyPI with ``--only-binary=:all:`` for an aarch64
platform and reads only the wheels' metadata (``--dry-run``); a dependency without such a wheel is
named. Needs PyPI; takes seconds.

``prove``: builds a Debian bookworm arm64 root from Debian's packages (mmdebstrap), copies the
checked-out project into it and, under qemu-user emulation (binfmt_misc), installs it with the
README's command, runs ``companion demo`` and a pytest selection (the fast tier by default). Needs
root, mmdebstrap, qemu-user-static with the aarch64 interpreter registered, Debian's mirror and PyPI.
Emulated timings mean nothing; only what ran and passed does.

    sudo python3 tools/arm64/check.py wheels
    sudo nice -n 10 python3 tools/arm64/check.py prove --root /tmp/arm64-root
    python3 tools/arm64/check.py docker   # buildx for linux/arm64,linux/amd64, or what is missing
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PYTHON_VERSION = "3.11"  # Debian bookworm's python3, and the Dockerfile's base image
# manylinux tags an aarch64 board with glibc 2.36 (bookworm) accepts, newest first; pip does not
# infer the older ones from a newer one when --platform is given
AARCH64_PLATFORMS = (*(f"manylinux_2_{minor}_aarch64" for minor in range(36, 16, -1)), "manylinux2014_aarch64")
DEBIAN_PACKAGES = ("python3", "python3-venv", "python3-pip", "ca-certificates", "git")
SRC_IN_ROOT = "/src"  # where the project is copied inside the root
HOST_CA_BUNDLE = "/etc/ssl/certs/ca-certificates.crt"
ROOT_CA_BUNDLE = "/etc/ssl/certs/host-ca-bundle.crt"


def runtime_requirements(pyproject: Path = REPO / "pyproject.toml") -> list[str]:
    """The ``[project] dependencies`` of pyproject.toml, comments stripped."""
    with pyproject.open("rb") as f:
        deps = tomllib.load(f)["project"]["dependencies"]
    if not deps:
        raise SystemExit(f"{pyproject}: [project] dependencies is empty")
    return [str(d) for d in deps]


def _pip_resolve(requirements: list[str], *, with_deps: bool) -> subprocess.CompletedProcess[str]:
    platform_args = [a for p in AARCH64_PLATFORMS for a in ("--platform", p)]
    with tempfile.TemporaryDirectory() as target:
        cmd = [
            sys.executable, "-m", "pip", "install", "--dry-run", "--quiet", "--ignore-installed",
            "--disable-pip-version-check", "--only-binary=:all:", *platform_args,
            "--python-version", PYTHON_VERSION, "--implementation", "cp",
            "--target", target, "--report", "-",
            *([] if with_deps else ["--no-deps"]), *requirements,
        ]  # fmt: skip
        return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


def _resolved(report_json: str) -> list[tuple[str, str, str]]:
    """(name, version, wheel file name) of each package in a pip ``--report``."""
    report = json.loads(report_json)
    out = []
    for item in report["install"]:
        meta = item["metadata"]
        out.append((meta["name"], meta["version"], item["download_info"]["url"].rsplit("/", 1)[-1]))
    return sorted(out, key=lambda r: r[0].lower())


def check_wheels(requirements: list[str] | None = None) -> int:
    """0 when every requirement (default: pyproject's runtime dependencies) and their closure resolve to
    aarch64/cp311 wheels; else 1, naming each one without."""
    requirements = runtime_requirements() if requirements is None else requirements
    missing: list[str] = []
    for req in requirements:
        r = _pip_resolve([req], with_deps=False)
        if r.returncode != 0:
            missing.append(req)
            print(f"NO aarch64 wheel: {req}\n  {_pip_error(r.stderr)}", file=sys.stderr)
            continue
        ((name, version, wheel),) = _resolved(r.stdout)
        print(f"ok  {req:45s} {name} {version}: {wheel}")
    if missing:
        print(f"{len(missing)} of {len(requirements)} runtime dependencies have no aarch64 wheel for "
              f"CPython {PYTHON_VERSION}: {', '.join(missing)}", file=sys.stderr)  # fmt: skip
        return 1
    closure = _pip_resolve(requirements, with_deps=True)
    if closure.returncode != 0:
        print(f"the dependency closure does not resolve to aarch64 wheels:\n  {_pip_error(closure.stderr)}",
              file=sys.stderr)  # fmt: skip
        return 1
    resolved = _resolved(closure.stdout)
    print(f"closure: {len(resolved)} packages, every one an aarch64 or pure-Python wheel:")
    for name, version, wheel in resolved:
        print(f"    {name} {version}: {wheel}")
    return 0


def _pip_error(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.startswith("ERROR")]
    return " / ".join(lines) or stderr.strip()[-500:]


# --- the full proof under qemu-user ---------------------------------------------------------------


def _require_host() -> None:
    problems = []
    if os.geteuid() != 0:
        problems.append("run as root (mmdebstrap --mode=root and chroot need it)")
    if shutil.which("mmdebstrap") is None:
        problems.append("mmdebstrap is not installed (apt-get install mmdebstrap)")
    binfmt = Path("/proc/sys/fs/binfmt_misc/qemu-aarch64")
    if not binfmt.exists():
        problems.append(
            f"{binfmt} is absent: mount binfmt_misc (mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc), "
            "apt-get install qemu-user-static binfmt-support, update-binfmts --enable qemu-aarch64"
        )
    elif "enabled" not in binfmt.read_text().splitlines()[0] or "F" not in _binfmt_flags(binfmt):
        problems.append(f"{binfmt} must be enabled with the F flag (qemu-user-static's registration)")
    if problems:
        raise SystemExit("cannot run the arm64 proof here:\n  " + "\n  ".join(problems))


def _binfmt_flags(entry: Path) -> str:
    m = re.search(r"^flags: (\S*)$", entry.read_text(), re.MULTILINE)
    return m.group(1) if m else ""


def _mirror() -> str:
    """The host's Debian mirror (deb822 sources), so the root comes from the same place apt uses."""
    sources = Path("/etc/apt/sources.list.d/debian.sources")
    if sources.exists():
        m = re.search(r"^URIs:\s*(\S+/debian)\s*$", sources.read_text(), re.MULTILINE)
        if m:
            return m.group(1)
    return "http://deb.debian.org/debian"


def build_root(root: Path) -> None:
    """A Debian bookworm arm64 root with python3, venv and pip, from Debian's packages."""
    if (root / "usr/bin/python3").exists():
        print(f"[arm64] reusing the root at {root}")
        return
    root.parent.mkdir(parents=True, exist_ok=True)
    cmd = ["mmdebstrap", "--mode=root", "--arch=arm64", "--variant=apt", f"--include={','.join(DEBIAN_PACKAGES)}",
           "bookworm", str(root), _mirror()]  # fmt: skip
    print("[arm64] " + " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True)


def copy_project(root: Path) -> str:
    """Copy the git-tracked files of the checkout into the root; return the commit (with -dirty if changed).

    The root's .venv is kept, so a second run reinstalls only what changed."""
    dest = root / SRC_IN_ROOT.lstrip("/")
    dest.mkdir(parents=True, exist_ok=True)
    for old in dest.iterdir():
        if old.name != ".venv":
            shutil.rmtree(old) if old.is_dir() and not old.is_symlink() else old.unlink()
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, check=True, capture_output=True).stdout
    for rel in files.decode().split("\0"):
        if rel and (REPO / rel).is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / rel, dest / rel)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, check=True, capture_output=True,
                            text=True).stdout.strip()  # fmt: skip
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO, capture_output=True,
                           text=True).stdout.strip()  # fmt: skip
    return commit + ("-dirty" if dirty else "")


@contextlib.contextmanager
def mounted(root: Path) -> Iterator[None]:
    """/proc, /sys, /dev, the host's resolv.conf and CA bundle inside the root; the mounts undone on exit."""
    shutil.copy2("/etc/resolv.conf", root / "etc/resolv.conf")
    # the root trusts what the host trusts (a network behind a TLS-inspecting proxy has its own CA)
    shutil.copy2(HOST_CA_BUNDLE, root / ROOT_CA_BUNDLE.lstrip("/"))
    mounts = [("proc", "proc", ["-t", "proc"]), ("sys", "sys", ["-t", "sysfs"]), ("/dev", "dev", ["--rbind"])]
    done: list[Path] = []
    try:
        for source, target, opts in mounts:
            point = root / target
            point.mkdir(exist_ok=True)
            subprocess.run(["mount", *opts, source, str(point)], check=True)
            done.append(point)
        yield
    finally:
        for point in reversed(done):
            subprocess.run(["umount", "--recursive", "--lazy", str(point)], check=False)


def in_root(root: Path, script: str, log: Path) -> int:
    """Run a shell script inside the root (aarch64 binaries, through qemu-user); tee its output to log."""
    env = {"PATH": "/usr/local/bin:/usr/bin:/bin", "HOME": "/root", "LANG": "C.UTF-8", "MPLBACKEND": "Agg",
           "PIP_DISABLE_PIP_VERSION_CHECK": "1", "PYTHONUNBUFFERED": "1", "PIP_DEFAULT_TIMEOUT": "180",
           "PIP_CERT": ROOT_CA_BUNDLE, "SSL_CERT_FILE": ROOT_CA_BUNDLE}  # fmt: skip
    print(f"[arm64] $ {script}", flush=True)
    with log.open("a") as f:
        f.write(f"\n$ {script}\n")
        f.flush()
        # chroot by its host path: env's PATH (the root's) is the one Popen searches
        chroot = shutil.which("chroot") or "/usr/sbin/chroot"
        proc = subprocess.Popen([chroot, str(root), "/bin/sh", "-c", f"cd {SRC_IN_ROOT} && {script}"],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
        assert proc.stdout is not None
        for line in proc.stdout:
            sys.stdout.write(line)
            f.write(line)
        rc = proc.wait()
        f.write(f"[exit {rc}]\n")
    print(f"[arm64] exit {rc}", flush=True)
    return rc


def prove(root: Path, pytest_args: str, log: Path) -> int:
    _require_host()
    build_root(root)
    commit = copy_project(root)
    log.write_text(f"arm64 proof of commit {commit}\n")
    steps = [
        ("machine", "uname -m && python3 -c 'import platform, sys; print(platform.machine(), sys.version)'"),
        # the README's command, word for word
        ("install+demo", "python3 -m venv .venv && .venv/bin/pip install -e . && .venv/bin/companion demo"),
        ("test extra", ".venv/bin/pip install -e '.[test]'"),
        ("pytest", f".venv/bin/python -m pytest -q -p no:cacheprovider {pytest_args}"),
    ]
    results = []
    with mounted(root):
        for name, script in steps:
            rc = in_root(root, script, log)
            results.append((name, rc))
            if rc != 0 and name != "pytest":
                break
    print(f"\n[arm64] commit {commit}; log {log}")
    for name, rc in results:
        print(f"[arm64]   {name:14s} {'passed' if rc == 0 else f'FAILED (exit {rc})'}")
    return 0 if all(rc == 0 for _, rc in results) and len(results) == len(steps) else 1


def docker_build(platforms: str) -> int:
    """``docker buildx build`` of the Dockerfile for both platforms, or what is missing for it, named."""
    docker = shutil.which("docker")
    if docker is None:
        print("cannot build the image: no docker CLI", file=sys.stderr)
        return 2
    checks = [
        ([docker, "buildx", "version"], "the buildx CLI plugin"),
        ([docker, "info", "--format", "{{.ServerVersion}}"], "a running docker daemon"),
    ]
    missing = [what for cmd, what in checks if subprocess.run(cmd, capture_output=True).returncode != 0]
    if not missing:
        builder = subprocess.run([docker, "buildx", "inspect", "--bootstrap"], capture_output=True, text=True)
        wanted = [p.strip() for p in platforms.split(",")]
        missing += [f"a buildx builder for {p}" for p in wanted if p not in builder.stdout]
    if missing:
        print(f"cannot build the image for {platforms}: missing {', '.join(missing)}", file=sys.stderr)
        return 2
    cmd = [docker, "buildx", "build", "--platform", platforms, "-t", "companion:latest", str(REPO)]
    print("[arm64] " + " ".join(cmd), flush=True)
    return subprocess.run(cmd).returncode


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("wheels", help="every runtime dependency has an aarch64 CPython 3.11 wheel (needs PyPI)")
    p = sub.add_parser("prove", help="install, demo and tests in a Debian arm64 root under qemu-user (needs root)")
    p.add_argument("--root", type=Path, default=Path("/tmp/arm64-root"), help="the arm64 root (kept for reuse)")
    p.add_argument("--pytest-args", default="", help="arguments for pytest inside the root (default: the fast tier)")
    p.add_argument("--log", type=Path, default=Path("/tmp/arm64-proof.log"), help="the transcript")
    d = sub.add_parser("docker", help="docker buildx build of the Dockerfile for arm64 and amd64, or what is missing")
    d.add_argument("--platforms", default="linux/arm64,linux/amd64")
    args = parser.parse_args(argv)
    if args.command == "wheels":
        return check_wheels()
    if args.command == "docker":
        return docker_build(args.platforms)
    return prove(args.root.resolve(), args.pytest_args, args.log)


if __name__ == "__main__":
    sys.exit(main())
