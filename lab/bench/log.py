"""``companion bench log``: what the flight logs cost a simulated flight.

Two measurements of the GPS-only demo flight, in one run:

* the logging's share: the same seeded flight flown without a run folder, with the CSV logs
  (the recorder's per-stream CSVs plus ``flight.csv`` and ``truth.csv``) but no ``flight.mcap``,
  with the CSV logs and ``flight.mcap``, and with the whole run folder (the CSVs, the MCAP and
  the MAVLink ``flight.tlog``), each ``rounds`` times interleaved, the fastest flight of each
  counting; shares are (logged - bare) / bare wall time; beside them the CPU time each adds
  in this process ((logged - bare) / bare, process CPU time, all threads) and the logging
  process's CPU time over the bare flight's CPU time, fastest flight of each, which the machine's
  other load moves far less than wall time;
* the whole run folder's share split in three, from two more variants flown in the same rounds:
  the folder opened and closed with nothing logged (every hook does nothing), and every row and
  ``.tlog`` record built and queued as usual but dropped where it would be handed over: opening
  and closing; building and queueing the rows on the loop; handing them over (pickle and send),
  the logging process's work on the other core and closing's wait for it;
* microseconds per row, from a further flight with the whole run folder in which this
  process's share is timed per stream: the recorder's hooks (row building and queueing on the
  control loop) and each log's batch as the writer thread takes it (handed to the logging
  process, or formatted and written here when logging in process). A hook is charged to its
  stream (a guidance tick's ``on_tick`` to ``guidance.csv``, with the ekf/events rows it
  writes); ``flight.csv`` is charged the shell's building and queueing of its row
  (``FlightLogObserver.on_tick``) and its batches, ``truth.csv`` its queueing and its batches,
  ``flight.tlog`` its hooks (one record per sample, setpoint, command or answer queued) and
  its batches. The hand-over itself (one pickle and send per wake-up,
  :mod:`companion.flightlog.logproc`) is timed as a whole and given per row, and so is the
  logging process's own CPU time (formatting, MCAP and MAVLink encoding, I/O: another core).
  Times in this process are CPU time of the thread doing the work (``time.thread_time``), so
  waiting for the GIL is not counted; reading that clock costs about a microsecond on some
  machines, so its cost per timed call, measured first, is subtracted.

Everything is reached through what the demo offers (:class:`~companion_lab.demo.DemoHooks`),
nothing is patched: the variants without ``flight.tlog`` or ``flight.mcap`` are
:func:`~companion_lab.demo.run_demo`'s ``tlog`` and ``mcap``; the folder with nothing logged is
flown with :class:`~companion.flightlog.recorder.NullRecorder` and
:class:`~companion.flightlog.csvlog.NullCsvLog`; the rows not handed over with the hand-over
that drops them (:func:`~companion.flightlog.hooks.drop_batches`); the timed flight with a stage
timer in :class:`~companion.flightlog.hooks.LogHooks` (the recorder's telemetry listener, the
logs' batches, the ``.tlog``'s hooks, ``truth.csv``'s queueing, the sends to the logging process)
and in :class:`~companion.delivery.hooks.ShellHooks` (stage ``logging``: ``flight.csv``'s
observer and the recorder's hooks as the shell's observer calls them).
"""

from __future__ import annotations

import functools
import logging
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

from companion.config import DEFAULT_PARAMS, shipped_params_path
from companion.delivery.hooks import ShellHooks
from companion.delivery.observers import FlightLogObserver, RecorderObserver
from companion.flightlog import logproc
from companion.flightlog.csvlog import NullCsvLog
from companion.flightlog.hooks import HAND_OVER, SAMPLES, LogHooks, batch_stage, drop_batches, row_stage
from companion.flightlog.mcap_encoding import MCAP_FILE
from companion.flightlog.recorder import NullRecorder
from companion.flightlog.streams import SAMPLE_FILES
from companion_lab import demo
from companion_lab.demo import DemoHooks
from companion_sitl.params import SimulatedConfig, load_simulated_config

log = logging.getLogger(__name__)

_HANDOVER = "(hand-over)"  # the pickles sent to the logging process (and the MCAP close's wait)
_TLOG = "flight.tlog"

# the recorder's hooks the shell's observer calls, and the stream each is charged to (its
# telemetry listener: the sample's own file)
_HOOK_STREAM = {
    "on_marker": "camera.csv",
    "on_uwb": "uwb.csv",
    "on_result": "requests.csv",
    "on_abort": "commands.csv",
    "on_command": "commands.csv",
    "on_tick": "guidance.csv",
    "on_setpoint": "setpoints.csv",
}

# the whole run folder opened and closed with nothing logged: every hook of the recorder, the
# simulator's .tlog and flight.csv/truth.csv does nothing (what is left is opening, the logging
# process's start-up messages, and closing)
NO_ROWS = DemoHooks(recorder=NullRecorder, csv_log=NullCsvLog)
# every row and .tlog record built and queued as usual, the batches dropped where they would be
# handed to the logging process (files opened and closed); one object, so every round's logs
# share one writer thread
ROWS_NOT_HANDED_OVER = DemoHooks(logs=LogHooks(hand_over=drop_batches))


def tlog_record_count(path: Path) -> int:
    """Whole records in a ``.tlog`` (8-byte timestamp + MAVLink 2 packet, walked from the start)."""
    data = path.read_bytes()
    pos = n = 0
    while pos + 11 <= len(data) and data[pos + 8] == 0xFD:
        end = pos + 8 + 12 + data[pos + 9] + (13 if data[pos + 10] & 1 else 0)
        if end > len(data):
            break
        pos, n = end, n + 1
    return n


def clock_overhead_s(n: int = 20000, rounds: int = 5) -> float:
    """What one timed interval measures with nothing in it: the cost of reading
    ``time.thread_time`` (the fastest of ``rounds``)."""
    clock = time.thread_time
    best = float("inf")
    for _ in range(rounds):
        total = 0.0
        for _ in range(n):
            t0 = clock()
            total += clock() - t0
        best = min(best, total / n)
    return best


def timed_hooks(hook_s: dict[str, float], write_s: dict[str, float], calls: dict[str, int]) -> DemoHooks:
    """The demo's hooks that charge the recorder's hooks, the .tlog's and every log's queueing
    and batches to streams (``calls``: timed calls per stream, each charged one clock reading too
    many): the logs' stage timer (:class:`~companion.flightlog.hooks.LogHooks`) and the shell's,
    whose ``"logging"`` stage wraps ``flight.csv``'s observer and the recorder's."""
    clock = time.thread_time

    def charged(fn: Callable[..., Any], spent: dict[str, float], stream: str, records: str = "") -> Callable[..., Any]:
        @functools.wraps(fn)
        def timed(*args: Any) -> Any:
            t0 = clock()
            r = fn(*args)
            spent[stream] += clock() - t0
            calls[stream] += 1
            if records:
                calls[records] += 1
            return r

        return timed

    def log_timer(stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        if stage == SAMPLES:  # the recorder's telemetry listener: charged to the sample's stream

            @functools.wraps(fn)
            def on_sample(sample: Any) -> None:
                t0 = clock()
                fn(sample)
                stream = SAMPLE_FILES.get(type(sample), "")
                hook_s[stream] += clock() - t0
                calls[stream] += 1

            return on_sample
        if stage == HAND_OVER:
            return charged(fn, write_s, _HANDOVER)
        if stage == row_stage(_TLOG):  # calls[_TLOG] also counts its batches taken
            return charged(fn, hook_s, _TLOG, _TLOG + " records")
        if stage == row_stage("truth.csv"):  # no recorder hook builds these rows
            return charged(fn, write_s, "truth.csv")
        name = stage.removesuffix(" batch")
        if stage == batch_stage(name) and name != MCAP_FILE:  # every CSV log's and the .tlog's
            return charged(fn, write_s, name)
        return fn

    def shell_timer(stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        owner, name = getattr(fn, "__self__", None), getattr(fn, "__name__", "")
        if stage == "logging" and name == "on_tick" and isinstance(owner, FlightLogObserver):
            return charged(fn, hook_s, "flight.csv")  # flight.csv's row, built and queued
        if stage == "logging" and name in _HOOK_STREAM and isinstance(owner, RecorderObserver):
            return charged(fn, hook_s, _HOOK_STREAM[name])
        return fn

    return DemoHooks(logs=LogHooks(stage_timer=log_timer), shell=ShellHooks(stage_timer=shell_timer))


def bench_log(seed: int = 1, config: SimulatedConfig | None = None, rounds: int = 2) -> dict[str, Any]:
    """Wall times of the GPS-only demo bare / with CSV logs / with the whole run folder, the
    logging shares, and per stream rows and microseconds per row (see the module doc)."""
    cfg = config or load_simulated_config(shipped_params_path(DEFAULT_PARAMS), overrides={"sim": {"seed": seed}})
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="bench-log-") as tmp:
        root = Path(tmp)
        # each variant flown `rounds` times, interleaved; the fastest flight of each counts (on a
        # shared machine the other load only ever adds time)
        walls: dict[str, list[float]] = defaultdict(list)
        cpus: dict[str, list[float]] = defaultdict(list)  # this process's CPU time per flight
        child_cpus: dict[str, list[float]] = defaultdict(list)  # the logging process's
        bare: Any = None

        def fly(variant: str, run_dir: Path | None, **options: Any) -> Any:
            proc = logproc.LogProcess._current
            c0 = proc.cpu_s() if proc is not None and run_dir is not None else None
            t0 = time.process_time()
            r = demo.run_demo(cfg, fusion=False, run_dir=run_dir, **options)
            cpus[variant].append(time.process_time() - t0)
            if c0 is not None and logproc.LogProcess._current is proc:
                c1 = proc.cpu_s()  # type: ignore[union-attr]
                if c1 is not None:
                    child_cpus[variant].append(c1 - c0)
            walls[variant].append(r.wall_time_s)
            return r

        for k in range(rounds):
            bare = fly("bare", None)
            fly("csv", root / f"csv{k}", tlog=False, mcap=False)
            fly("mcap", root / f"mcap{k}", tlog=False)
            fly("full", root / f"full{k}")
            if logproc.client() is not None:  # the split of the whole folder's cost
                fly("fixed", root / f"fixed{k}", hooks=NO_ROWS)
                fly("queued", root / f"queued{k}", hooks=ROWS_NOT_HANDED_OVER)
        mcap_bytes = (root / "mcap0" / MCAP_FILE).stat().st_size
        hook_s: dict[str, float] = defaultdict(float)
        write_s: dict[str, float] = defaultdict(float)
        calls: dict[str, int] = defaultdict(int)
        overhead = clock_overhead_s()
        proc = logproc.client()
        cpu0 = proc.cpu_s() if proc is not None else None
        demo.run_demo(cfg, fusion=False, run_dir=root / "timed", hooks=timed_hooks(hook_s, write_s, calls))
        proc_after = logproc.client()
        cpu1 = proc_after.cpu_s() if proc_after is not None and proc_after is proc else None
        rows = {f.name: max(0, sum(1 for _ in f.open(encoding="utf-8")) - 1) for f in (root / "timed").glob("*.csv")}
        rows[_TLOG] = calls[_TLOG + " records"]  # queued by its own hooks (setpoints, commands, answers)
        tlog_records = tlog_record_count(root / "timed" / _TLOG)
    out["sim_time_s"] = bare.sim_time_s
    b, c, m, f = (min(walls[k]) for k in ("bare", "csv", "mcap", "full"))
    out["rounds"] = rounds
    out["bare_wall_s"] = b
    out["csv_logs_wall_s"] = c
    out["csv_mcap_logs_wall_s"] = m
    out["full_run_folder_wall_s"] = f
    out["csv_logging_share"] = (c - b) / b
    out["csv_mcap_logging_share"] = (m - b) / b
    out["mcap_vs_csv_share"] = (m - c) / c
    out["mcap_bytes"] = mcap_bytes
    out["full_logging_share"] = (f - b) / b
    if walls["fixed"] and walls["queued"]:
        # the whole folder's share, split: opening and closing; building and queueing the rows
        # on the loop; handing them over (pickle, send), the logging process and closing's wait
        x, q = min(walls["fixed"]), min(walls["queued"])
        out["split_open_close_share"] = (x - b) / b
        out["split_rows_share"] = (q - x) / b
        out["split_handover_share"] = (f - q) / b
    # CPU time, fastest flight of each: what the other load on the machine moves least
    cb = min(cpus["bare"])
    for key, variant in (("csv", "csv"), ("csv_mcap", "mcap"), ("full", "full")):
        out[f"{key}_cpu_share"] = (min(cpus[variant]) - cb) / cb
        if child_cpus[variant]:
            out[f"{key}_logging_process_cpu_share"] = min(child_cpus[variant]) / cb
    out["rows"] = sum(rows.values())
    out["clock_overhead_us"] = overhead * 1e6
    total = 0.0
    for name in sorted(rows):
        spent = max(0.0, hook_s.get(name, 0.0) + write_s.get(name, 0.0) - overhead * calls.get(name, 0))
        total += spent
        if rows[name]:
            out[f"{name}_us_per_row"] = spent / rows[name] * 1e6
            out[f"{name}_rows"] = rows[name]
    out["all_streams_us_per_row"] = total / max(1, out["rows"]) * 1e6
    out["log_writer"] = "by the logging process" if cpu0 is not None and cpu1 is not None else "in process"
    handover = max(0.0, write_s.get(_HANDOVER, 0.0) - overhead * calls.get(_HANDOVER, 0))
    out["us_per_row_handover"] = handover / max(1, out["rows"]) * 1e6
    out["us_per_row_this_process"] = out["all_streams_us_per_row"] + out["us_per_row_handover"]
    out["this_process_share"] = (total + handover) / b
    out["this_process_ms"] = (total + handover) * 1e3
    out["tlog_records"] = tlog_records
    out["tlog_records_of_samples"] = tlog_records - rows[_TLOG]
    if cpu0 is not None and cpu1 is not None:
        out["logging_process_cpu_s"] = cpu1 - cpu0
        out["us_per_row_logging_process"] = (cpu1 - cpu0) / max(1, out["rows"]) * 1e6
    return out
