"""Driver plugins, found through entry points (colcon-style).

Groups: ``companion.cameras``, ``companion.uwb``, ``companion.payloads``. A plugin is a class
registered under a group by any installed distribution (ours in ``plugins/`` and ``sitl/``, or a
third party's), declaring ``api_version``; the app selects one by name from config. A plugin that
fails to import, or declares another API version, is reported by name with the reason and the
others still load.

Interface, version 1 (start / read or act / stop):
- camera: ``start()``, ``read() -> Frame | None`` (newest frame, stamped at capture), ``stop()``
- uwb: ``start()``, ``read() -> list`` of readings since the last call, ``stop()``
- payload: ``start()``, ``async release()``, ``stop()``
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from importlib import metadata
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

log = logging.getLogger(__name__)

API_VERSION = 1
GROUPS = ("companion.cameras", "companion.uwb", "companion.payloads")


class PluginError(RuntimeError):
    """A plugin could not be found, loaded or started."""


@dataclass(frozen=True, slots=True)
class Frame:
    time_s: float  # exposure time on the shell's monotonic clock
    image: np.ndarray
    index: int


@runtime_checkable
class Driver(Protocol):
    api_version: ClassVar[int]

    def start(self) -> None: ...

    def stop(self) -> None: ...


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
