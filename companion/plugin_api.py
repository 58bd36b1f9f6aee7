"""Driver plugins, found through entry points (colcon-style).

Groups: ``companion.cameras``, ``companion.uwb``, ``companion.payloads``. A plugin is a class
registered under a group by any installed distribution (ours in ``plugins/`` and ``sitl/``, or a
third party's), declaring ``api_version``; the app selects one by name from config. A plugin that
fails to import, or declares another API version, is reported by name with the reason and the
others still load.

Interface, version 1 (start / read or act / stop):
- camera: ``start()``, ``read() -> Frame | None`` (newest frame, stamped at capture), ``stop()``;
  a frame may also carry the driver's own capture stamp and its arrival time
  (:class:`Frame`: ``capture_time_s``, ``arrival_time_s``; docs/clock.md), which
  ``landing.camera_time`` then uses instead of the configured latency
- uwb: ``start()``, ``read() -> list`` of readings since the last call, ``stop()``
- payload: ``start()``, ``async release()``, ``stop()``

Optional capabilities, each versioned on its own (a plugin that lacks one still loads and works
as before; one that declares a version this companion does not speak is used without it):

- camera frame listener, version 1 (:data:`FRAME_LISTENER_VERSION`): the camera declares
  ``frame_listener_version = 1`` and has ``set_frame_listener(callback)``. ``callback()`` (no
  arguments) is called each time a new frame becomes readable, from whatever thread the camera
  produces frames on (its capture thread); it returns at once and the app then calls ``read()``.
  ``set_frame_listener(None)`` detaches: once it returns, the old callback is not called again.
  An exception raised by the callback is logged by the camera and never ends its capture.
  :class:`FrameListenerSlot` implements that contract for a plugin. A camera without the
  capability (or which reports ``frame_listener_version = None``, e.g. a mode without a capture
  thread) is polled at the landing kit's rate.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

log = logging.getLogger(__name__)

API_VERSION = 1
GROUPS = ("companion.cameras", "companion.uwb", "companion.payloads")
FRAME_LISTENER_VERSION = 1  # the camera frame-listener capability this companion speaks


class PluginError(RuntimeError):
    """A plugin could not be found, loaded or started."""


@dataclass(frozen=True, slots=True)
class Frame:
    """A camera frame. ``time_s``: its exposure time on the shell's monotonic clock as the plugin
    knows it (a driver without a stamp of its own: the arrival minus ``landing.camera_latency_s``).
    Optional, both on the shell's monotonic clock (docs/clock.md): ``capture_time_s``, the
    driver's own capture stamp (a V4L2 buffer's ``CLOCK_MONOTONIC`` timestamp, a sensor's
    start-of-exposure time mapped by the driver); ``arrival_time_s``, when the frame reached the
    plugin. None: the plugin does not know it."""

    time_s: float
    image: np.ndarray
    index: int
    capture_time_s: float | None = None
    arrival_time_s: float | None = None


@runtime_checkable
class Driver(Protocol):
    api_version: ClassVar[int]

    def start(self) -> None: ...

    def stop(self) -> None: ...


@runtime_checkable
class FrameNotifier(Protocol):
    """A camera offering the frame-listener capability (see the module's docstring)."""

    frame_listener_version: int | None

    def set_frame_listener(self, callback: Callable[[], None] | None) -> None: ...


def frame_listener_of(camera: Any) -> Callable[[Callable[[], None] | None], None] | None:
    """``camera.set_frame_listener`` when the camera offers the frame-listener capability at
    :data:`FRAME_LISTENER_VERSION`; None when it does not (poll it). A camera declaring another
    version is logged once here and polled."""
    version = getattr(camera, "frame_listener_version", None)
    setter = getattr(camera, "set_frame_listener", None)
    if version is None or not callable(setter):
        return None
    if version != FRAME_LISTENER_VERSION:
        log.warning(
            "camera %s declares frame_listener_version %r, this companion speaks %d: polling it instead",
            type(camera).__name__,
            version,
            FRAME_LISTENER_VERSION,
        )
        return None
    return setter  # type: ignore[no-any-return]


class FrameListenerSlot:
    """A camera plugin's frame listener (capability version 1): set from the app's thread, called
    from the capture thread. :meth:`notify` never raises: a listener's exception is counted and
    logged (the first, then every 100th) and capture goes on. Once :meth:`set` returns, a listener
    it replaced is not called again (the call and the swap hold one lock, re-entrant so that a
    listener may detach itself)."""

    def __init__(self, owner: str) -> None:
        self.owner = owner
        self._callback: Callable[[], None] | None = None
        self._lock = threading.RLock()
        self.notified = 0
        self.errors = 0

    @property
    def attached(self) -> bool:
        return self._callback is not None

    def set(self, callback: Callable[[], None] | None) -> None:
        with self._lock:
            self._callback = callback

    def notify(self) -> None:
        """Tell the listener, if any, that a new frame is readable."""
        with self._lock:
            cb = self._callback
            if cb is None:
                return
            self.notified += 1
            try:
                cb()
            except Exception as err:  # the listener's failure must not end the capture thread
                self.errors += 1
                if self.errors == 1 or self.errors % 100 == 0:
                    log.error(
                        "camera %s: frame listener raised %s: %s (%d so far); capture goes on",
                        self.owner,
                        type(err).__name__,
                        err,
                        self.errors,
                        exc_info=self.errors == 1,
                    )


@dataclass(frozen=True)
class PluginInfo:
    group: str
    name: str
    target: str
    distribution: str
    ok: bool
    error: str = ""


def _entry_points(group: str) -> list[metadata.EntryPoint]:
    return sorted(metadata.entry_points(group=group), key=lambda e: e.name)


def discover(group: str) -> tuple[dict[str, type[Any]], list[PluginInfo]]:
    """Load every plugin of ``group``: (name -> class, report of each, good or bad)."""
    if group not in GROUPS:
        raise PluginError(f"unknown plugin group {group!r}; groups are {GROUPS}")
    loaded: dict[str, type[Any]] = {}
    report = []
    for ep in _entry_points(group):
        dist = ep.dist.name if ep.dist is not None else "?"
        try:
            cls = ep.load()
            ver = getattr(cls, "api_version", None)
            if ver != API_VERSION:
                raise PluginError(f"declares api_version {ver!r}, this companion speaks {API_VERSION}")
        except Exception as err:  # any failure in third-party code is reported, never fatal
            msg = f"{type(err).__name__}: {err}"
            log.warning("plugin %s/%s (%s) failed to load: %s", group, ep.name, ep.value, msg)
            report.append(PluginInfo(group, ep.name, ep.value, dist, False, msg))
            continue
        loaded[ep.name] = cls
        report.append(PluginInfo(group, ep.name, ep.value, dist, True))
    return loaded, report


def create(group: str, name: str, **kwargs: Any) -> Any:
    """Instantiate the plugin ``name`` of ``group`` with keyword arguments from config."""
    loaded, report = discover(group)
    if name in loaded:
        return loaded[name](**kwargs)
    bad = next((r for r in report if r.name == name), None)
    if bad is not None:
        raise PluginError(f"plugin {group}/{name} is installed but failed to load: {bad.error}")
    raise PluginError(f"no plugin {group}/{name}; installed: {sorted(loaded)}")
