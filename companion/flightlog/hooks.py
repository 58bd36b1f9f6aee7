"""How a bench or a test instruments a flight's logs without changing what they write:
:class:`LogHooks`, whose every field defaults to what a flight uses (``companion bench log``).

- ``stage_timer``: a function ``(stage, fn) -> fn`` the logs wrap their own named stages with,
  once, where they bind them (never per call). None (a flight): nothing is wrapped, nothing
  costs. The stages:

  - :data:`SAMPLES`: the :class:`~companion.flightlog.recorder.FlightRecorder`'s listener of the
    telemetry cache, called with each sample (the sample's type says its stream);
  - ``"<file> batch"`` (:func:`batch_stage`): each batch of the log written to ``<file>`` as the
    shared writer thread (or the log's close) takes it: handed to the logging process, or
    formatted and written here when logging in process;
  - ``"<file> row"`` (:func:`row_stage`): queueing one row or record where its producer binds
    the log's hook: the simulator's ``.tlog`` hooks (:meth:`TelemetryTlog.use_hooks
    <companion.flightlog.telemetry_tlog.TelemetryTlog.use_hooks>`), the demo's ``truth.csv``;
  - :data:`HAND_OVER`: each send to the logging process (the writer thread's one pickle and send
    per wake-up, and the wait of a ``flight.mcap``'s close).

- ``hand_over``: how a log's batches reach the logging process, ``(process) -> post``, ``post``
  taking one batch op and returning whether it was taken (False: the process is gone, the log
  continues in process). :func:`post_to` (a flight: :meth:`LogProcess.post
  <companion.flightlog.logproc.LogProcess.post>`), or :func:`drop_batches` (every batch
  dropped where it would be handed over: the files opened and closed, nothing written).

Logs opened with hooks other than the default are served by a writer thread of their own (one
per distinct hooks), so what their wake-ups send is timed as theirs alone.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from companion.flightlog.logproc import LogProcess
    from companion.flightlog.logproc_wire import Op

F = TypeVar("F", bound=Callable[..., Any])

StageTimer = Callable[[str, Callable[..., Any]], Callable[..., Any]]
Post = Callable[["Op"], bool]
HandOver = Callable[["LogProcess"], Post]

SAMPLES = "samples"
HAND_OVER = "hand-over"


def batch_stage(file_name: str) -> str:
    """The stage of a log's batches (``"flight.csv batch"``)."""
    return f"{file_name} batch"


def row_stage(file_name: str) -> str:
    """The stage of queueing one row or record (``"flight.tlog row"``)."""
    return f"{file_name} row"


def post_to(proc: LogProcess) -> Post:
    """A flight's hand-over: the logging process's :meth:`~companion.flightlog.logproc.LogProcess.post`."""
    return proc.post


def _taken(op: Op) -> bool:
    return True


def drop_batches(proc: LogProcess) -> Post:
    """A hand-over that drops every batch (taken, never sent): what building and queueing the
    rows cost without handing them over (``companion bench log``)."""
    return _taken


@dataclass(frozen=True)
class LogHooks:
    stage_timer: StageTimer | None = None
    hand_over: HandOver = post_to

    def timed(self, stage: str, fn: F) -> F:
        """``fn`` timed as ``stage`` when a stage timer is set, else ``fn`` itself."""
        return fn if self.stage_timer is None else self.stage_timer(stage, fn)  # type: ignore[return-value]


FLIGHT = LogHooks()
"""A flight's hooks: nothing timed, every batch handed over."""
