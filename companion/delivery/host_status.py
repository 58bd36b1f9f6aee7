"""What the companion computer reports of itself in ONBOARD_COMPUTER_STATUS: uptime, load of each
CPU core, temperatures and memory, read from Linux's /proc and /sys. A value that cannot be read
(another OS, a board without thermal zones) goes out as MAVLink's "unknown" for its field."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

UINT8_UNKNOWN = 255
INT8_UNKNOWN = 127
UINT32_UNKNOWN = 0xFFFFFFFF
CPU_CORES = 8  # ONBOARD_COMPUTER_STATUS.cpu_cores has room for 8
TEMP_CORES = 8


@dataclass(frozen=True, slots=True)
class HostStatus:
    """One reading; ``None`` where the host does not say."""

    uptime_s: float
    cpu_load_pct: tuple[int, ...]  # per core, 0..100, since the previous reading
    temperature_board_c: float | None
    temperature_cores_c: tuple[float, ...]
    ram_used_mib: int | None
    ram_total_mib: int | None


class HostStatusReader:
    """Reads :class:`HostStatus`; CPU load is the busy share of each core's time between two reads."""

    def __init__(self, proc: Path = Path("/proc"), sys_thermal: Path = Path("/sys/class/thermal")) -> None:
        self.proc = proc
        self.sys_thermal = sys_thermal
        self._t0 = time.monotonic()
        self._last_cpu: list[tuple[int, int]] | None = None

    def read(self) -> HostStatus:
        return HostStatus(
            self._uptime_s(),
            self._cpu_load(),
            *self._temperatures(),
            *self._memory(),
        )

    def _uptime_s(self) -> float:
        try:
            return float((self.proc / "uptime").read_text().split()[0])
        except (OSError, ValueError, IndexError):
            return time.monotonic() - self._t0  # the process's, where the host's is not readable

    def _cpu_times(self) -> list[tuple[int, int]] | None:
        """(busy, total) jiffies of each core from /proc/stat."""
        try:
            lines = (self.proc / "stat").read_text().splitlines()
        except OSError:
            return None
        out = []
        for line in lines:
            parts = line.split()
            if not parts or not parts[0].startswith("cpu") or parts[0] == "cpu":
                continue
            try:
                v = [int(x) for x in parts[1:]]
            except ValueError:
                return None
            idle = v[3] + (v[4] if len(v) > 4 else 0)  # idle + iowait
            out.append((sum(v) - idle, sum(v)))
        return out or None

    def _cpu_load(self) -> tuple[int, ...]:
        now = self._cpu_times()
        last, self._last_cpu = self._last_cpu, now
        if now is None or last is None or len(now) != len(last):
            return ()
        loads = []
        for (b1, t1), (b0, t0) in zip(now, last, strict=True):
            dt = t1 - t0
            loads.append(round(100.0 * (b1 - b0) / dt) if dt > 0 else 0)
        return tuple(min(100, max(0, x)) for x in loads)

    def _temperatures(self) -> tuple[float | None, tuple[float, ...]]:
        """The first thermal zone as the board's, the others by zone (millidegrees in /sys)."""
        temps: list[float] = []
        try:
            zones = sorted(self.sys_thermal.glob("thermal_zone*"), key=lambda p: int(p.name[12:] or 0))
        except (OSError, ValueError):
            zones = []
        for z in zones:
            try:
                temps.append(int((z / "temp").read_text().strip()) / 1000.0)
            except (OSError, ValueError):
                continue
        if not temps:
            return None, ()
        return temps[0], tuple(temps[1:])

    def _memory(self) -> tuple[int | None, int | None]:
        try:
            info = {}
            for line in (self.proc / "meminfo").read_text().splitlines():
                k, _, rest = line.partition(":")
                info[k] = int(rest.split()[0])  # kB
            total = info["MemTotal"]
            avail = info.get("MemAvailable", info.get("MemFree", 0))
        except (OSError, ValueError, KeyError, IndexError):
            return None, None
        return (total - avail) // 1024, total // 1024


def onboard_computer_status(s: HostStatus, time_usec: int) -> dict[str, Any]:
    """ONBOARD_COMPUTER_STATUS fields of one reading (unknowns as MAVLink's unused values)."""

    def clamp_i8(c: float | None) -> int:
        return INT8_UNKNOWN if c is None else int(max(-128, min(126, round(c))))

    cores = list(s.cpu_load_pct[:CPU_CORES]) + [UINT8_UNKNOWN] * (CPU_CORES - min(CPU_CORES, len(s.cpu_load_pct)))
    tcores = [clamp_i8(c) for c in s.temperature_cores_c[:TEMP_CORES]]
    tcores += [INT8_UNKNOWN] * (TEMP_CORES - len(tcores))
    return {
        "time_usec": int(time_usec),
        "uptime": int(s.uptime_s * 1000) & 0xFFFFFFFF,
        "type": 0,
        "cpu_cores": cores,
        "cpu_combined": [UINT8_UNKNOWN] * 10,
        "gpu_cores": [UINT8_UNKNOWN] * 4,
        "gpu_combined": [UINT8_UNKNOWN] * 10,
        "temperature_board": clamp_i8(s.temperature_board_c),
        "temperature_core": tcores,
        "fan_speed": [0] * 4,
        "ram_usage": UINT32_UNKNOWN if s.ram_used_mib is None else int(s.ram_used_mib),
        "ram_total": UINT32_UNKNOWN if s.ram_total_mib is None else int(s.ram_total_mib),
        "storage_type": [0] * 4,
        "storage_usage": [0] * 4,
        "storage_total": [0] * 4,
        "link_type": [0] * 6,
        "link_tx_rate": [0] * 6,
        "link_rx_rate": [0] * 6,
        "link_tx_max": [0] * 6,
        "link_rx_max": [0] * 6,
    }
