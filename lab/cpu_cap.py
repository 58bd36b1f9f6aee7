"""A Pi-sized CPU budget: run a command, or this process, in a child cgroup with a CPU quota.

The quota is a fraction of one core of this machine: cgroup v2 ``cpu.max`` ("QUOTA PERIOD") where
a cgroup2 hierarchy has the cpu controller, cgroup v1 ``cpu.cfs_quota_us`` / ``cpu.cfs_period_us``
otherwise. When neither is writable the error names the file that was not.

The ``pi4`` factor: the share of one core of this machine that one Raspberry Pi 4 core gives, from
the Computer Language Benchmarks Game's n-body program in CPython (five million steps), which a
published measurement ran on a Pi 4 at 1.5 GHz in 158.26 s (performance governor; see
:data:`PI4_NBODY_5M_S`). :func:`calibrate` runs the same program here and divides; its CPU time, not
wall time, so that the machine's other load moves it little. CPython is what the companion runs,
and the figure is conservative: the Pi's run used an older CPython than ours (3.11 is faster on
this program), so the factor is, if anything, smaller than a like-for-like one.

``python -m companion_lab.cpu_cap calibrate`` prints the factor; ``python -m companion_lab.cpu_cap
run --cap pi4 -- CMD ...`` runs CMD capped (root, or write access to the cgroup tree).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import logging
import math
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

log = logging.getLogger(__name__)

# https://chaitanyamehta.github.io/projects/performance-analysis-of-programming-languages : the
# n-body benchmark, five million steps, CPython on a Raspberry Pi 4 Model B (4 GB, Rev 1.1) at
# 1.5 GHz, performance governor: 158.263 s (on-demand 158.393 s, powersave at 600 MHz 401.476 s)
PI4_NBODY_5M_S = 158.263
PI4_NBODY_SOURCE = (
    "n-body (Benchmarks Game), 5e6 steps, CPython, Raspberry Pi 4 B at 1.5 GHz: 158.263 s "
    "(chaitanyamehta.github.io/projects/performance-analysis-of-programming-languages)"
)
NBODY_STEPS = 5_000_000
# n-body's own check: the system's energy before and after 1000 steps of 0.01 (the Benchmarks Game's
# published output for n = 1000)
NBODY_ENERGY_1000 = (-0.169075164, -0.169087605)
# measured with calibrate() on the development machine (AMD EPYC, Zen 4, CPython 3.11.7), CPU time
# of the 5e6 steps; the factor pi4 = this / PI4_NBODY_5M_S (see docs/cpu-budget.md)
EPYC_NBODY_5M_S = 20.53
# one Raspberry Pi 4 core (1.5 GHz) as a share of one core of the development machine: 0.130
PI4_FACTOR = round(EPYC_NBODY_5M_S / PI4_NBODY_5M_S, 3)
# The CFS period: a cgroup that has used its quota is stopped until the period ends, so a long
# period turns a slower CPU into one that freezes (at 0.13 of a core and the kernel's 100 ms, for
# up to 87 ms at a time: longer than a guidance tick). 10 ms keeps each stall under 9 ms, the
# nearest to a uniformly slower core that a quota gives; the period grows only where the quota
# would fall under the kernel's 1 ms floor (caps under 0.1 of a core).
PERIOD_US = 10_000
MIN_QUOTA_US = 1_000  # the kernel refuses a CFS quota under 1 ms


def period_for(fraction: float) -> int:
    """The CFS period for ``fraction`` of one core: :data:`PERIOD_US`, or longer where the quota
    would fall under the kernel's 1 ms floor."""
    return max(PERIOD_US, math.ceil(MIN_QUOTA_US / fraction)) if fraction > 0 else PERIOD_US


class CpuCapError(RuntimeError):
    """The CPU cap could not be set up (the message names the file and what was expected)."""


# ---------------------------------------------------------------------------- the factor
def parse_cap(text: str, pi4_factor: float | None = None) -> float:
    """The fraction of one core that ``text`` asks for: ``pi4``, a fraction (``0.25``) or a
    percentage (``25%``). Outside (0, 64] (64 cores) it is an error."""
    s = text.strip().lower()
    if s == "pi4":
        f = pi4_factor if pi4_factor is not None else PI4_FACTOR
    else:
        try:
            f = float(s[:-1]) / 100.0 if s.endswith("%") else float(s)
        except ValueError:
            raise CpuCapError(
                f"--cpu-cap {text!r}: expected 'pi4', a fraction of one core (e.g. 0.25) or a percentage (25%)"
            ) from None
    if not (math.isfinite(f) and 0.0 < f <= 64.0):
        raise CpuCapError(f"--cpu-cap {text!r}: the fraction of one core must be in (0, 64], got {f:g}")
    return f


def quota_us(fraction: float, period_us: int = PERIOD_US) -> int:
    """CFS quota in microseconds for ``fraction`` of one core over ``period_us``."""
    if not (1_000 <= period_us <= 1_000_000):
        raise CpuCapError(f"CPU period {period_us} us: the kernel takes 1000-1000000 us")
    if not (math.isfinite(fraction) and fraction > 0.0):
        raise CpuCapError(f"CPU cap {fraction!r}: must be a positive fraction of one core")
    return max(MIN_QUOTA_US, round(fraction * period_us))


def _advance(n: int, bodies: list[tuple[list[float], list[float], float]]) -> None:
    pairs = [(bodies[i], bodies[j]) for i in range(len(bodies)) for j in range(i + 1, len(bodies))]
    dt = 0.01
    for _ in range(n):
        for ([x1, y1, z1], v1, m1), ([x2, y2, z2], v2, m2) in pairs:
            dx, dy, dz = x1 - x2, y1 - y2, z1 - z2
            mag = dt * ((dx * dx + dy * dy + dz * dz) ** (-1.5))
            b1m, b2m = m1 * mag, m2 * mag
            v1[0] -= dx * b2m
            v1[1] -= dy * b2m
            v1[2] -= dz * b2m
            v2[0] += dx * b1m
            v2[1] += dy * b1m
            v2[2] += dz * b1m
        for r, [vx, vy, vz], _m in bodies:
            r[0] += dt * vx
            r[1] += dt * vy
            r[2] += dt * vz


def _bodies() -> list[tuple[list[float], list[float], float]]:
    pi = 3.14159265358979323
    sm, dpy = 4 * pi * pi, 365.24
    raw = [
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1.0),
        (
            (4.84143144246472090e00, -1.16032004402742839e00, -1.03622044471123109e-01),
            (1.66007664274403694e-03, 7.69901118419740425e-03, -6.90460016972063023e-05),
            9.54791938424326609e-04,
        ),
        (
            (8.34336671824457987e00, 4.12479856412430479e00, -4.03523417114321381e-01),
            (-2.76742510726862411e-03, 4.99852801234917238e-03, 2.30417297573763929e-05),
            2.85885980666130812e-04,
        ),
        (
            (1.28943695621391310e01, -1.51111514016986312e01, -2.23307578892655734e-01),
            (2.96460137564761618e-03, 2.37847173959480950e-03, -2.96589568540237556e-05),
            4.36624404335156298e-05,
        ),
        (
            (1.53796971148509165e01, -2.59193146099879641e01, 1.79258772950371181e-01),
            (2.68067772490389322e-03, 1.62824170038242295e-03, -9.51592254519715870e-05),
            5.15138902046611451e-05,
        ),
    ]
    bodies = [(list(r), [v * dpy for v in vel], m * sm) for r, vel, m in raw]
    px = sum(v[0] * m for _, v, m in bodies)
    py = sum(v[1] * m for _, v, m in bodies)
    pz = sum(v[2] * m for _, v, m in bodies)
    sun = bodies[0]
    sun[1][:] = [-px / sun[2], -py / sun[2], -pz / sun[2]]
    return bodies


def nbody_energy(bodies: list[tuple[list[float], list[float], float]]) -> float:
    e = 0.0
    for i, (r1, v1, m1) in enumerate(bodies):
        e += m1 * (v1[0] ** 2 + v1[1] ** 2 + v1[2] ** 2) / 2.0
        for r2, _v2, m2 in bodies[i + 1 :]:
            e -= m1 * m2 / math.dist(r1, r2)
    return e


def nbody(steps: int) -> tuple[float, float, float]:
    """(energy before, energy after, CPU seconds of the steps) of the n-body program."""
    bodies = _bodies()
    e0 = nbody_energy(bodies)
    t0 = time.process_time()
    _advance(steps, bodies)
    return e0, nbody_energy(bodies), time.process_time() - t0


@dataclasses.dataclass(frozen=True)
class Calibration:
    this_core_s: float  # CPU seconds of the 5e6 n-body steps here
    pi4_s: float
    factor: float  # share of one core of this machine that a Pi 4 core gives


def calibrate(steps: int = NBODY_STEPS) -> Calibration:
    e0, e1, _ = nbody(1000)
    if (round(e0, 9), round(e1, 9)) != NBODY_ENERGY_1000:
        raise CpuCapError(f"n-body check failed: energies {e0:.9f} / {e1:.9f}, expected {NBODY_ENERGY_1000}")
    _, _, cpu_s = nbody(steps)
    here_5m = cpu_s * NBODY_STEPS / steps
    return Calibration(here_5m, PI4_NBODY_5M_S, here_5m / PI4_NBODY_5M_S)


@functools.cache
def pi4_factor_here(steps: int = 500_000) -> float:
    """One Pi 4 core's share of this machine's core, measured now (a tenth of :func:`calibrate`'s
    run, ~3 s): the built-in :data:`PI4_FACTOR` is one machine's; a host whose cores run slower
    (or a virtual machine's, shared) gets its own, so a cap means a Pi 4 core wherever it runs."""
    return calibrate(steps).factor


# ---------------------------------------------------------------------------- the cgroup
@dataclasses.dataclass(frozen=True)
class CpuController:
    version: int  # 1 or 2
    path: Path  # the cgroup directory children are made under


def find_cpu_controller(mountinfo: str, proc_cgroup: str, prefix: Path = Path("/")) -> CpuController:
    """Where this process's cpu controller lives: a cgroup2 mount whose ``cgroup.controllers``
    lists ``cpu`` first, else a cgroup v1 mount with the ``cpu`` option. ``prefix`` roots the paths
    (a test's fake tree)."""
    v1_mount: Path | None = None
    v2_mount: Path | None = None
    for line in mountinfo.splitlines():
        parts = line.split(" - ", 1)
        if len(parts) != 2:
            continue
        fields, tail = parts[0].split(), parts[1].split()
        if len(fields) < 5 or len(tail) < 3:
            continue
        mnt, fstype, opts = fields[4], tail[0], tail[2].split(",")
        if fstype == "cgroup2" and v2_mount is None:
            v2_mount = Path(mnt)
        elif fstype == "cgroup" and "cpu" in opts and v1_mount is None:
            v1_mount = Path(mnt)
    v1_rel = v2_rel = "/"
    for line in proc_cgroup.splitlines():
        hid, ctrls, rel = [*line.split(":", 2), "", ""][:3]
        if hid == "0" and ctrls == "":
            v2_rel = rel or "/"
        elif "cpu" in ctrls.split(","):
            v1_rel = rel or "/"
    if v2_mount is not None:
        ctl = prefix / v2_mount.relative_to("/") / "cgroup.controllers"
        with contextlib.suppress(OSError):
            if "cpu" in ctl.read_text().split():
                return CpuController(2, prefix / v2_mount.relative_to("/") / v2_rel.lstrip("/"))
    if v1_mount is not None:
        return CpuController(1, prefix / v1_mount.relative_to("/") / v1_rel.lstrip("/"))
    raise CpuCapError(
        "no cgroup cpu controller: /proc/self/mountinfo has neither a cgroup2 mount whose "
        "cgroup.controllers lists cpu nor a cgroup v1 mount with the cpu option"
    )


def _write(path: Path, value: str) -> None:
    try:
        path.write_text(value)
    except OSError as e:
        raise CpuCapError(
            f"{path}: cannot write {value.strip()!r} ({e.strerror or e}); the CPU cap needs "
            "root or write access to this cgroup file"
        ) from e


class CpuCgroup:
    """A child cgroup with a CPU quota; processes or (cgroup v1) single threads are moved in with
    :meth:`add_pid` / :meth:`add_tid` and back to the parent by :meth:`remove`."""

    def __init__(self, controller: CpuController, fraction: float, name: str, period_us: int | None = None):
        self.controller = controller
        self.fraction = fraction
        self.period_us = period_us = period_us if period_us is not None else period_for(fraction)
        self.quota_us = quota_us(fraction, period_us)
        self.path = controller.path / name
        try:
            self.path.mkdir(exist_ok=True)
        except OSError as e:
            raise CpuCapError(f"{self.path}: cannot create the cgroup ({e.strerror or e})") from e
        if controller.version == 2:
            # the parent must hand the cpu controller to its children
            _write(controller.path / "cgroup.subtree_control", "+cpu")
            _write(self.path / "cpu.max", f"{self.quota_us} {period_us}\n")
        else:
            _write(self.path / "cpu.cfs_period_us", f"{period_us}\n")
            _write(self.path / "cpu.cfs_quota_us", f"{self.quota_us}\n")

    def describe(self) -> str:
        f = "cpu.max" if self.controller.version == 2 else "cpu.cfs_quota_us"
        return (
            f"{self.fraction:.3f} of one core ({f} {self.quota_us} us per {self.period_us} us, "
            f"cgroup v{self.controller.version} {self.path})"
        )

    def add_pid(self, pid: int) -> None:
        """Move a whole process (every thread) in."""
        _write(self.path / "cgroup.procs", f"{pid}\n")

    def add_tid(self, tid: int) -> None:
        """Move one thread in (cgroup v1 only: v2 keeps a process's threads in one domain)."""
        if self.controller.version != 1:
            raise CpuCapError(f"{self.path}: single threads can be moved only on cgroup v1")
        _write(self.path / "tasks", f"{tid}\n")

    def release_tid(self, tid: int) -> None:
        """Move one thread back to the parent (cgroup v1)."""
        _write(self.controller.path / "tasks", f"{tid}\n")

    def throttled(self) -> dict[str, int]:
        """``cpu.stat``: periods, throttled periods and time (the kernel's own count)."""
        out: dict[str, int] = {}
        with contextlib.suppress(OSError):
            for line in (self.path / "cpu.stat").read_text().splitlines():
                k, _, v = line.partition(" ")
                if v.strip().isdigit():
                    out[k] = int(v)
        return out

    def remove(self, attempts: int = 50) -> bool:
        """Move what is left back to the parent and delete the cgroup; True when it is gone. A thread
        started from inside while the others move out lands inside again (the kernel then refuses
        the deletion): moved and tried again, ``attempts`` times 10 ms apart; a cgroup left behind is
        logged with its path."""
        procs = self.path / ("cgroup.procs" if self.controller.version == 2 else "tasks")
        errors: dict[str, str] = {}
        for _ in range(attempts):
            with contextlib.suppress(OSError):
                for tid in procs.read_text().split():
                    try:
                        (self.controller.path / procs.name).write_text(tid + "\n")
                    except OSError as e:
                        errors[tid] = e.strerror or str(e)
            try:
                self.path.rmdir()
                return True
            except FileNotFoundError:
                return True
            except OSError as e:
                errors["rmdir"] = e.strerror or str(e)
                time.sleep(0.01)
        left = procs.read_text().split() if procs.exists() else []
        log.info(
            "%s: not deleted yet (tasks %s%s): the kernel keeps a cgroup while exited tasks still refer to "
            "it; the next cap deletes it",
            self.path,
            " ".join(left) or "none listed",
            "; " + ", ".join(f"{t}: {e}" for t, e in errors.items()) if errors else "",
        )
        return False


CGROUP_PREFIX = "companion-cpucap-"


def sweep_stale(controller: CpuController) -> list[Path]:
    """Delete the caps earlier runs left behind (empty by now; one still in use is refused by the
    kernel and stays). The ones deleted."""
    gone = []
    for d in sorted(controller.path.glob(CGROUP_PREFIX + "*")):
        try:
            d.rmdir()
        except OSError:
            continue
        gone.append(d)
    return gone


def open_cgroup(fraction: float, name: str | None = None, period_us: int | None = None) -> CpuCgroup:
    """A capped child cgroup of this process's own cgroup (``period_us``: see :data:`PERIOD_US`)."""
    ctl = find_cpu_controller(Path("/proc/self/mountinfo").read_text(), Path("/proc/self/cgroup").read_text())
    sweep_stale(ctl)
    return CpuCgroup(ctl, fraction, name or f"{CGROUP_PREFIX}{os.getpid()}", period_us)


def cap_unavailable() -> str:
    """Why no CPU cap can be set here ('' when one can): a probe cgroup opened and removed."""
    try:
        open_cgroup(0.5, f"companion-cpucap-probe-{os.getpid()}").remove()
    except (CpuCapError, OSError) as err:
        return str(err)
    return ""


# threads that stand in for the world, not the companion: the MAVLink sim vehicle, the camera's
# rendering, the real firmware's truth reader, and the keeper itself
WORLD_THREAD_PREFIXES = ("mavlink-sim", "dart-link-camera", "sim-camera-render", "truth-feed", "cpu-cap-keeper")


class CapKeeper:
    """Keeps the companion, and only it, in ``cgroup``: the threads that stand in for the world
    (:data:`WORLD_THREAD_PREFIXES`) moved back out (cgroup v1 moves single threads; under v2 a
    process's threads share one cgroup and :attr:`world_inside` says so), this process's logging
    process moved into ``logging_cgroup`` (its own core's worth: it exists to run on another core,
    and a Pi has four), or into ``cgroup`` when there is none. Threads come and go: :meth:`sweep`
    again every ``period_s`` (:meth:`run` on the loop, or :meth:`start` on a thread of its own)."""

    def __init__(self, cgroup: CpuCgroup, period_s: float = 0.2, logging_cgroup: CpuCgroup | None = None) -> None:
        self.cgroup = cgroup
        self.logging_cgroup = logging_cgroup if logging_cgroup is not None else cgroup
        self.period_s = period_s
        self.world_inside = cgroup.controller.version != 1
        self.released: set[int] = set()
        self._logging_pid: int | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def sweep(self) -> None:
        from companion.flightlog import logproc

        if not self.world_inside:
            for t in threading.enumerate():
                tid = t.native_id
                if tid is None or tid in self.released or not t.name.startswith(WORLD_THREAD_PREFIXES):
                    continue
                with contextlib.suppress(CpuCapError):
                    self.cgroup.release_tid(tid)
                    self.released.add(tid)
        cur = logproc.LogProcess._current
        if cur is not None and not cur.dead and cur.pid == os.getpid() and cur.child.pid != self._logging_pid:
            self.logging_cgroup.add_pid(cur.child.pid)
            self._logging_pid = cur.child.pid

    async def run(self) -> None:
        import asyncio

        while True:
            self.sweep()
            await asyncio.sleep(self.period_s)

    def start(self) -> None:
        """Sweep on a daemon thread of its own (itself a world thread, so outside the cap)."""

        def loop() -> None:
            while not self._stop.wait(self.period_s):
                self.sweep()

        self.sweep()
        self._thread = threading.Thread(target=loop, name="cpu-cap-keeper", daemon=True)
        self._thread.start()

    @property
    def native_thread_id(self) -> int | None:
        """The keeper thread's kernel thread id while :meth:`start` runs it (None before and after)."""
        return None if self._thread is None else self._thread.native_id

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None


@contextlib.contextmanager
def capped_process(fraction: float, period_us: int | None = None, world_outside: bool = False) -> Iterator[CpuCgroup]:
    """This whole process (and what it starts from now on) capped for the ``with`` block; with
    ``world_outside``, a :class:`CapKeeper` keeps the world's stand-ins out of it."""
    cg = open_cgroup(fraction, period_us=period_us)
    keeper = CapKeeper(cg) if world_outside else None
    try:
        cg.add_pid(os.getpid())
        if keeper is not None:
            keeper.start()
        yield cg
    finally:
        if keeper is not None:
            keeper.stop()
        cg.remove()


def run_capped(cmd: list[str], fraction: float) -> int:
    """Run ``cmd`` in a capped cgroup; its exit code."""
    cg = open_cgroup(fraction)
    procs = str(cg.path / "cgroup.procs")
    if not os.access(procs, os.W_OK):
        cg.remove()
        raise CpuCapError(f"{procs}: not writable; the CPU cap needs root or write access to this cgroup file")

    def enter() -> None:  # in the child, before exec: "0" moves the writer itself
        with open(procs, "w") as f:
            f.write("0\n")

    try:
        proc = subprocess.Popen(cmd, preexec_fn=enter)  # the child joins the cgroup before exec
        rc = proc.wait()
        st = cg.throttled()
        print(
            f"cpu_cap: {cg.describe()}: exit {rc}; throttled in {st.get('nr_throttled', 0)} of "
            f"{st.get('nr_periods', 0)} periods",
            file=sys.stderr,
        )
        return rc
    finally:
        cg.remove()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m companion_lab.cpu_cap", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("calibrate", help="run n-body here and print the pi4 factor")
    rp = sub.add_parser("run", help="run a command in a capped cgroup")
    rp.add_argument("--cap", required=True, help="pi4, a fraction of one core (0.25) or a percentage (25%%)")
    rp.add_argument("command", nargs=argparse.REMAINDER)
    args = ap.parse_args(argv)
    try:
        if args.cmd == "calibrate":
            c = calibrate()
            print(
                f"n-body 5e6 steps: {c.this_core_s:.2f} s CPU here, {c.pi4_s:.2f} s on a Pi 4 at 1.5 GHz "
                f"-> a Pi 4 core is {c.factor:.3f} of this core (built-in pi4 factor {PI4_FACTOR:.3f})"
            )
            return 0
        cmd = args.command[1:] if args.command[:1] == ["--"] else args.command
        if not cmd:
            ap.error("run: no command given (python -m companion_lab.cpu_cap run --cap pi4 -- CMD ...)")
        return run_capped(cmd, parse_cap(args.cap))
    except CpuCapError as e:
        print(f"cpu_cap: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
