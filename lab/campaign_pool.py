"""A landing campaign's landings flown in worker processes (``companion campaign landing --jobs N``).

Each landing depends on its draw alone (:func:`companion_lab.campaign_landing.fly_landing`), so
they fly in any order in any process; the rows are put back in the campaign's order, and the
result is the sequential one, bit for bit.

Workers are *spawned* (a fresh interpreter each): the parent may run threads (the progress bar's
refresh, a telemetry session) that a fork would copy mid-operation. A worker ignores SIGINT:
Ctrl-C is the parent's, which stops the workers and raises ``KeyboardInterrupt``; a worker ends
with its parent however that ends (killed included). A landing that
raises, or a worker that dies, ends the campaign with :class:`CampaignLandingError` naming the
landing (index, seed, variant): each worker reports the landing it starts.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing
import os
import signal
import sys
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.process import BaseProcess
from multiprocessing.queues import SimpleQueue
from typing import Any

from companion_lab.campaign_landing import CampaignLandingError, LandingTask, fly_landing, renders_camera

log = logging.getLogger(__name__)

#: in a worker: where it reports (pid, index) of each landing it starts to the parent
_reports: SimpleQueue[tuple[int, int]] | None = None


def _die_with_parent(parent_pid: int) -> None:
    """A worker ends when its parent does, however that ends (Linux: PR_SET_PDEATHSIG)."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError) as err:
            log.debug("worker %d: PR_SET_PDEATHSIG not set: %s", os.getpid(), err)
    if os.getppid() != parent_pid:  # the parent ended before that
        os._exit(1)


def _init_worker(level: int, reports: SimpleQueue[tuple[int, int]], parent_pid: int) -> None:
    global _reports
    _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the parent's to handle
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s[%(process)d]: %(message)s")
    _reports = reports


def _fly(task: LandingTask) -> dict[str, Any]:
    if _reports is not None:
        _reports.put((os.getpid(), task.index))
    try:
        return fly_landing(task)
    except Exception as err:
        # raised here as one error that pickles whatever it wraps (the executor attaches this
        # worker's traceback as its cause)
        raise CampaignLandingError(
            f"{task.name()} failed in worker {os.getpid()}: {type(err).__name__}: {err}"
        ) from None


class _Workers:
    """What the parent knows of its workers: their processes (the children started since it was
    made) and the landing each one flies (as the workers report it)."""

    def __init__(self, reports: SimpleQueue[tuple[int, int]]) -> None:
        self.reports = reports
        self.before = set(multiprocessing.active_children())
        self.procs: dict[int, BaseProcess] = {}
        self.flying: dict[int, int] = {}  # pid -> index of the landing it started last

    def drain(self) -> None:
        for c in multiprocessing.active_children():
            if c not in self.before and c.pid is not None:
                self.procs[c.pid] = c
        while not self.reports.empty():
            pid, index = self.reports.get()
            self.flying[pid] = index

    def in_flight(self, done: set[int]) -> dict[int, int]:
        self.drain()
        return {pid: i for pid, i in self.flying.items() if i not in done}

    def stop(self) -> None:
        self.drain()
        for p in self.procs.values():
            if p.is_alive():
                p.terminate()
        for p in self.procs.values():
            p.join(timeout=5.0)


def _died(workers: _Workers, tasks: list[LandingTask], done: set[int]) -> str:
    """The message for a worker that died: the landing it was flying (by its exit code, when the
    executor has terminated the others), else every landing in flight."""
    flying = workers.in_flight(done)
    end = time.monotonic() + 5.0  # the executor is stopping the others and reaping them all
    while any(p.exitcode is None for p in workers.procs.values()) and time.monotonic() < end:
        time.sleep(0.05)
    dead = {pid: workers.procs[pid].exitcode for pid in flying if pid in workers.procs}
    culprit = {pid: code for pid, code in dead.items() if code not in (None, 0, -signal.SIGTERM)}
    named = culprit or dead or dict.fromkeys(flying)
    if not named:
        return "a worker process died before it started a landing"
    parts = []
    for pid, code in named.items():
        how = f"signal {-code}" if code is not None and code < 0 else f"exit code {code}"
        parts.append(f"{tasks[flying[pid]].name()} (worker {pid}, {how})")
    lead = "a worker process died while flying" if culprit else "a worker process died; in flight:"
    return f"{lead} {', '.join(parts)}"


def fly_in_pool(
    tasks: list[LandingTask], jobs: int, finished: Callable[[LandingTask, dict[str, Any], int], None]
) -> list[dict[str, Any]]:
    """Fly ``tasks`` in ``jobs`` spawned worker processes; their rows in the order of ``tasks``.
    ``finished(task, row, done)`` is called in this process as each landing comes back."""
    ctx = multiprocessing.get_context("spawn")
    reports: SimpleQueue[tuple[int, int]] = ctx.SimpleQueue()
    rows: list[dict[str, Any] | None] = [None] * len(tasks)
    done: set[int] = set()
    level = logging.getLogger().getEffectiveLevel()
    t0 = time.perf_counter()
    log.info("flying %d landings in %d worker processes", len(tasks), jobs)
    workers = _Workers(reports)
    pool = ProcessPoolExecutor(jobs, mp_context=ctx, initializer=_init_worker, initargs=(level, reports, os.getpid()))
    try:
        # the landings that render the camera are the long ones: handed out first, the short ones
        # fill the end (the rows go back in the campaign's order whatever the order they fly in)
        order = sorted(tasks, key=lambda t: (not renders_camera(t.variant), t.index))
        futures: dict[Future[dict[str, Any]], LandingTask] = {pool.submit(_fly, t): t for t in order}
        pending = set(futures)
        while pending:
            ready, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
            workers.drain()
            for fut in sorted(ready, key=lambda f: futures[f].index):
                task = futures[fut]
                try:
                    row = fut.result()
                except BrokenProcessPool:
                    raise CampaignLandingError(_died(workers, tasks, done)) from None
                rows[task.index] = row
                done.add(task.index)
                finished(task, row, len(done))
    except BaseException as err:
        if isinstance(err, KeyboardInterrupt):
            flying = workers.in_flight(done)
            log.warning(
                "interrupted after %d of %d landings (%.0f s); stopping the workers (in flight: %s)",
                len(done),
                len(tasks),
                time.perf_counter() - t0,
                ", ".join(tasks[i].name() for i in sorted(flying.values())) or "none",
            )
        pool.shutdown(wait=False, cancel_futures=True)
        workers.drain()
        workers.stop()
        raise
    pool.shutdown(wait=True)
    return [r for r in rows if r is not None]
