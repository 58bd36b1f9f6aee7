"""The detector's worker thread: its priority, set once, and the CPU time each detection takes.

The camera step runs the pad detector on the event loop's executor in flight; that thread runs
below the loop (``runtime.vision_thread_nice``, or SCHED_RR one below the loop's
``runtime.realtime_priority``) so a detection never takes the CPU from guidance, and the CPU
seconds it spent feed the detection pacer (``runtime.vision_cpu_budget``).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from typing import Any

from companion.scheduling import set_thread_realtime, vision_thread_priority

log = logging.getLogger(__name__)

_thread_priority: dict[int, tuple[int, int]] = {}  # tid -> (nice, realtime priority) applied


def prioritise_this_thread(nice: int, realtime: int = 0) -> None:
    """The detector thread's priority, set once per setting (Linux: a thread id is a pid to
    setpriority): SCHED_RR one below the loop's ``realtime`` when that is set, otherwise the lower
    ``nice``; where that is not possible the thread keeps its priority, said once."""
    tid = threading.get_native_id()
    if (nice <= 0 and realtime <= 0) or _thread_priority.get(tid) == (nice, realtime):
        return
    _thread_priority[tid] = (nice, realtime)
    if realtime > 0:
        why = set_thread_realtime(vision_thread_priority(realtime))
        if why is not None:
            log.warning("runtime.realtime_priority = %d: the detector thread keeps its policy (%s)", realtime, why)
        return
    try:
        os.setpriority(os.PRIO_PROCESS, tid, nice)
    except (OSError, AttributeError) as err:
        log.warning("runtime.vision_thread_nice = %d: the detector thread keeps its priority (%s)", nice, err)


def cpu_timed(fn: Callable[..., Any], *args: Any, nice: int = 0, realtime: int = 0) -> tuple[Any, float]:
    """``fn(*args)`` and the CPU seconds its thread spent in it (the thread prioritised first, see
    ``runtime.vision_thread_nice`` and ``runtime.realtime_priority``)."""
    prioritise_this_thread(nice, realtime)
    t0 = time.thread_time()
    out = fn(*args)
    return out, time.thread_time() - t0
