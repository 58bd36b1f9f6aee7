#!/usr/bin/env python3
"""Build the Dockerfile's image without Docker Hub or a docker daemon, and run it (docs/flying.md).

1. a Debian bookworm root with python3 and python3-venv, from Debian's packages (mmdebstrap), as a
   tarball cached under ~/.cache/companion-docker (``$XDG_CACHE_HOME`` if set; ``--refresh`` builds
   it again), imported as the local base image ``localhost/bookworm-python:3.11[-ARCH]``;
2. ``buildah build`` of the Dockerfile on that base (``--build-arg BASE_IMAGE=...``, ``--layers`` so
   an unchanged stage is reused), with the host pip's index (``PIP_INDEX_URL``) and its CA bundle as
   the build secret ``pip_cert``: a TLS-inspecting proxy works and nothing of the host is kept in
   the image;
3. ``podman run`` of the image: ``companion demo`` (``--demo``; it must print DELIVERED), and the
   fast tier (``--fast-tier``: the Dockerfile's ``test`` target, run with ``--network none``).

Needs root, ``apt-get install mmdebstrap buildah podman`` (and runc where crun cannot run
containers), Debian's mirror and PyPI. ``--arch arm64`` builds and runs the arm64 image under
qemu-user (``apt-get install qemu-user-static binfmt-support``); slow, only what passes counts.

    sudo python3 tools/docker/build.py --demo --fast-tier
    sudo python3 tools/docker/build.py --arch arm64 --demo
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SUITE = "bookworm"
DEBIAN_PACKAGES = ("python3", "python3-venv", "ca-certificates", "passwd")
MIRRORS = (
    "deb http://deb.debian.org/debian bookworm main",
    "deb http://deb.debian.org/debian bookworm-updates main",
    "deb http://deb.debian.org/debian-security bookworm-security main",
)
HOST_CA_BUNDLE = "/etc/ssl/certs/ca-certificates.crt"
# How podman is asked to run a container, tried in order until one runs the base image: plain; then
# for a sandbox where crun cannot run containers (cgroups v1 hybrid: "cgroups in hybrid mode not
# supported") and the default rlimits cannot be raised (no CAP_SYS_RESOURCE), runc with lower ones.
RUN_OPTIONS = (
    (),
    ("--runtime", "runc", "--ulimit", "nofile=4096:4096", "--ulimit", "nproc=4096:4096"),
)


class Unavailable(RuntimeError):
    """What this machine lacks to build or run the image (a test skips with it)."""


def log(msg: str) -> None:
    print(f"[docker] {msg}", flush=True)


def cache_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "companion-docker"


def base_image(arch: str) -> str:
    return "localhost/bookworm-python:3.11" + ("" if arch == "amd64" else f"-{arch}")


def image_tag(arch: str, target: str = "runtime") -> str:
    return (
        "localhost/companion:" + ("latest" if target == "runtime" else target) + ("" if arch == "amd64" else f"-{arch}")
    )


def host_arch() -> str:
    """The host's architecture in Debian's (and the OCI's) words: amd64, arm64, ..."""
    machine = platform.machine()
    return {"x86_64": "amd64", "aarch64": "arm64"}.get(machine, machine)


def require_host(arch: str) -> None:
    """Raises Unavailable naming everything missing."""
    problems = []
    if os.geteuid() != 0:
        problems.append("not root (mmdebstrap --mode=root and rootful buildah/podman need it)")
    for tool, package in (("mmdebstrap", "mmdebstrap"), ("buildah", "buildah"), ("podman", "podman")):
        if shutil.which(tool) is None:
            problems.append(f"{tool} is not installed (apt-get install {package})")
    if arch != host_arch():
        qemu = {"arm64": "aarch64"}.get(arch, arch)
        entry = Path(f"/proc/sys/fs/binfmt_misc/qemu-{qemu}")
        if not entry.exists() or "enabled" not in entry.read_text():
            problems.append(
                f"no qemu-{qemu} registered in binfmt_misc (apt-get install qemu-user-static binfmt-support)"
            )
    if problems:
        raise Unavailable("; ".join(problems))


def host_pip() -> dict[str, str]:
    """The host pip's index URL (when set, http/https only) and CA bundle: what the build's pip uses."""
    out = subprocess.run([sys.executable, "-m", "pip", "config", "list"], capture_output=True, text=True).stdout
    conf = {}
    for line in out.splitlines():
        key, _, value = line.partition("=")
        conf[key.split(".")[-1]] = value.strip().strip("'\"")
    result = {}
    index = os.environ.get("PIP_INDEX_URL") or conf.get("index-url", "")
    if index.startswith(("http://", "https://")):
        result["index"] = index
    cert = os.environ.get("PIP_CERT") or conf.get("cert") or HOST_CA_BUNDLE
    if Path(cert).is_file():
        result["cert"] = cert
    return result


def base_tarball(arch: str, refresh: bool) -> Path:
    """The cached bookworm root for ``arch`` (built with mmdebstrap when absent or ``refresh``)."""
    tar = cache_dir() / f"bookworm-python-{arch}.tar"
    if tar.exists() and not refresh:
        log(f"reusing {tar} ({tar.stat().st_size / 1e6:.0f} MB); --refresh builds it again")
        return tar
    tar.parent.mkdir(parents=True, exist_ok=True)
    partial = tar.with_suffix(".partial.tar")
    cmd = [
        "mmdebstrap",
        "--mode=root",
        f"--arch={arch}",
        "--variant=apt",
        f"--include={','.join(DEBIAN_PACKAGES)}",
        SUITE,
        str(partial),
        *MIRRORS,
    ]
    log(" ".join(repr(c) if " " in c else c for c in cmd))
    t0 = time.monotonic()
    subprocess.run(cmd, check=True)
    partial.replace(tar)
    log(f"base root: {tar.stat().st_size / 1e6:.0f} MB in {time.monotonic() - t0:.0f} s")
    return tar


def _image_exists(name: str) -> bool:
    return subprocess.run(["buildah", "inspect", "--type", "image", name], capture_output=True).returncode == 0


def import_base(tar: Path, arch: str) -> str:
    """The tarball as the image base_image(arch), unless that image was imported from this tarball."""
    name = base_image(arch)
    stamp = f"{tar.stat().st_size}-{int(tar.stat().st_mtime)}"
    if _image_exists(name):
        info = json.loads(
            subprocess.run(
                ["buildah", "inspect", "--type", "image", name], capture_output=True, text=True, check=True
            ).stdout
        )
        if (info["OCIv1"].get("config", {}).get("Labels") or {}).get("companion.base-tarball") == stamp:
            log(f"reusing the base image {name}")
            return name
    ctr = subprocess.run(["buildah", "from", "--arch", arch, "scratch"], capture_output=True, text=True, check=True)
    c = ctr.stdout.strip()
    try:
        subprocess.run(["buildah", "add", c, str(tar), "/"], check=True, capture_output=True)
        subprocess.run(
            [
                "buildah",
                "config",
                "--arch",
                arch,
                "--os",
                "linux",
                "--cmd",
                "/bin/bash",
                "--env",
                "LANG=C.UTF-8",
                "--label",
                f"companion.base-tarball={stamp}",
                "--label",
                "org.opencontainers.image.description=Debian bookworm with python3 and "
                "python3-venv (mmdebstrap, tools/docker/build.py)",
                c,
            ],
            check=True,
        )
        subprocess.run(["buildah", "commit", "--rm", "-q", c, name], check=True, capture_output=True)
    except BaseException:
        subprocess.run(["buildah", "rm", c], capture_output=True)
        raise
    log(f"imported {tar.name} as {name}")
    return name


def run_options(image: str) -> tuple[str, ...]:
    """The first RUN_OPTIONS with which podman runs ``image``; Unavailable (with podman's errors) if none."""
    errors = []
    for opts in RUN_OPTIONS:
        if "runc" in opts and shutil.which("runc") is None:
            errors.append("runc is not installed (apt-get install runc)")
            continue
        r = subprocess.run(
            [
                "podman",
                "run",
                "--rm",
                "--network",
                "none",
                *opts,
                "--entrypoint",
                "python3",
                image,
                "-c",
                "print('ok')",
            ],
            capture_output=True,
            text=True,
        )
        if r.returncode == 0 and r.stdout.strip() == "ok":
            if opts:
                log("podman runs containers here with: " + " ".join(opts))
            return opts
        last = (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1]
        errors.append(f"podman run {' '.join(opts)}: {last}")
    raise Unavailable("podman cannot run a container here: " + " | ".join(errors))


def export_git(rev: str) -> Path:
    """``git archive REV`` into a temporary folder (the checkout is not touched)."""
    ctx = Path(tempfile.mkdtemp(prefix="companion-docker-ctx-"))
    archive = subprocess.run(["git", "-C", str(REPO), "archive", rev], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(ctx)], input=archive, check=True)
    return ctx


def build(context: Path, arch: str, base: str, target: str, isolation: str) -> float:
    """``buildah build`` of the Dockerfile's ``target``; its wall time."""
    pip = host_pip()
    cmd = [
        "buildah",
        "build",
        "--layers",
        "--isolation",
        isolation,
        "--network",
        "host",
        "--platform",
        f"linux/{arch}",
        "--build-arg",
        f"BASE_IMAGE={base}",
        "--target",
        target,
        "-t",
        image_tag(arch, target),
    ]
    if "index" in pip:
        cmd += ["--build-arg", f"PIP_INDEX_URL={pip['index']}"]
    if "cert" in pip:
        cmd += ["--secret", f"id=pip_cert,src={pip['cert']}"]
    log(" ".join([*cmd, str(context)]))
    t0 = time.monotonic()
    subprocess.run([*cmd, str(context)], check=True)
    return time.monotonic() - t0


def image_size_mb(name: str) -> float:
    out = subprocess.run(
        ["podman", "image", "inspect", "--format", "{{.Size}}", name], capture_output=True, text=True, check=True
    ).stdout
    return int(out.strip()) / 1e6


def run(image: str, opts: tuple[str, ...], args: list[str], network: str = "none") -> tuple[int, str, float]:
    """``podman run --rm IMAGE ARGS...`` (the image's entry point), echoed; exit code, output, seconds."""
    cmd = ["podman", "run", "--rm", "--network", network, *opts, image, *args]
    log(" ".join(cmd))
    t0 = time.monotonic()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = []
    assert p.stdout is not None
    for line in p.stdout:
        print(line, end="", flush=True)
        out.append(line)
    return p.wait(), "".join(out), time.monotonic() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--arch", default=None, help="amd64 or arm64 (default: the host's)")
    parser.add_argument("--refresh", action="store_true", help="build the cached base root again")
    parser.add_argument("--git", metavar="REV", help="build REV (git archive) instead of the checkout as it is")
    parser.add_argument(
        "--isolation", default="chroot", help="buildah's RUN isolation (default chroot: no cgroups needed)"
    )
    parser.add_argument("--demo", action="store_true", help="run `companion demo` in the image; it must deliver")
    parser.add_argument("--fast-tier", action="store_true", help="build the test target and run the fast tier in it")
    parser.add_argument(
        "--pytest-args", default="-q -n 2 -p no:cacheprovider", help="the test image's pytest arguments"
    )
    args = parser.parse_args(argv)
    arch = args.arch or host_arch()
    try:
        require_host(arch)
    except Unavailable as err:
        print(f"cannot build the image: {err}", file=sys.stderr)
        return 2
    results: list[tuple[str, str]] = []
    t0 = time.monotonic()
    base = import_base(base_tarball(arch, args.refresh), arch)
    results.append(("base", f"{base}, {image_size_mb(base):.0f} MB"))
    context = export_git(args.git) if args.git else REPO
    try:
        seconds = build(context, arch, base, "runtime", args.isolation)
        tag = image_tag(arch)
        results.append(("image", f"{tag}, {image_size_mb(tag):.0f} MB, built in {seconds:.0f} s"))
        ok = True
        try:
            opts = run_options(base) if args.demo or args.fast_tier else ()
        except Unavailable as err:
            print(f"cannot run the image: {err}", file=sys.stderr)
            return 2
        if args.demo:
            rc, out, seconds = run(image_tag(arch), opts, ["demo"])
            delivered = rc == 0 and "DELIVERED, returned home" in out
            ok &= delivered
            verdict = "DELIVERED, returned home" if delivered else f"FAILED (exit {rc})"
            results.append(("demo", f"{verdict} in {seconds:.0f} s"))
        if args.fast_tier:
            seconds = build(context, arch, base, "test", args.isolation)
            rc, out, _ = run(image_tag(arch, "test"), opts, args.pytest_args.split())
            ok &= rc == 0
            tail = (out.strip().splitlines() or [""])[-1].strip("= ")
            verdict = "passed" if rc == 0 else f"FAILED (exit {rc})"
            size = image_size_mb(image_tag(arch, "test"))
            results.append(("fast tier", f"{verdict}: {tail}; test image built in {seconds:.0f} s, {size:.0f} MB"))
    finally:
        if args.git:
            shutil.rmtree(context, ignore_errors=True)
    log(f"summary ({arch}, {time.monotonic() - t0:.0f} s in all):")
    for name, what in results:
        log(f"  {name:10s} {what}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
