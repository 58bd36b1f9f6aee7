"""A ground station on the autopilot's GCS link, as QGroundControl would be (docs/gcs.md): it
heartbeats as 255/190, keeps what arrives by source (system, component), and sends COMMAND_LONGs
to any component, waiting for that component's COMMAND_ACK. Used to check that the companion's
own component is seen and commanded through the firmware's routing (PX4 SIH: UDP 14550;
ArduCopter SITL: a SERIALn link)."""

from __future__ import annotations

import logging
import threading
import time
from collections import defaultdict
from dataclasses import dataclass
from typing import Any

from pymavlink import mavutil

log = logging.getLogger(__name__)

MAV_TYPE_GCS = 6
MAV_AUTOPILOT_INVALID = 8


class GcsProbe:
    def __init__(self, url: str, source_system: int = 255, source_component: int = 190) -> None:
        self.url = url
        self.source_system = source_system
        self.source_component = source_component
        self._conn: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._by_source: dict[tuple[int, int], list[Any]] = defaultdict(list)
        self.heartbeats_sent = 0

    def start(self) -> GcsProbe:
        self._conn = mavutil.mavlink_connection(
            self.url, source_system=self.source_system, source_component=self.source_component
        )
        self._thread = threading.Thread(target=self._run, name="gcs-probe", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def __enter__(self) -> GcsProbe:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        conn = self._conn
        next_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                next_hb = now + 1.0
                try:
                    conn.mav.heartbeat_send(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, 0)
                    self.heartbeats_sent += 1
                except OSError as err:  # udpin before the first packet has no peer yet
                    log.debug("GCS heartbeat not sent: %s", err)
            try:
                m = conn.recv_match(blocking=True, timeout=0.1)
            except Exception as err:
                log.debug("GCS probe: bad packet: %s", err)
                continue
            if m is None or m.get_type() == "BAD_DATA":
                continue
            with self._lock:
                self._by_source[(m.get_srcSystem(), m.get_srcComponent())].append(m)

    def messages(self, system: int, component: int, kind: str | None = None) -> list[Any]:
        with self._lock:
            msgs = list(self._by_source.get((system, component), ()))
        return [m for m in msgs if kind is None or m.get_type() == kind]

    def sources(self) -> set[tuple[int, int]]:
        with self._lock:
            return set(self._by_source)

    def texts(self, system: int, component: int) -> list[tuple[int, str]]:
        """(severity, text) of the STATUSTEXTs from a component, chunks joined."""
        out: list[tuple[int, str]] = []
        chunks: dict[int, list[str]] = {}
        for m in self.messages(system, component, "STATUSTEXT"):
            text = m.text if isinstance(m.text, str) else bytes(m.text).decode(errors="replace")
            text = text.rstrip("\x00")
            if getattr(m, "id", 0):
                chunks.setdefault(m.id, []).append(text)
                if len(text) < 50:
                    out.append((m.severity, "".join(chunks.pop(m.id))))
            else:
                out.append((m.severity, text))
        return out

    def command(
        self, target_system: int, target_component: int, command: int, *params: float, timeout_s: float = 3.0
    ) -> int | None:
        """Send a COMMAND_LONG (again every 0.5 s, confirmation counting up) until the target
        component's COMMAND_ACK for it arrives; its MAV_RESULT, None without one."""
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        seen = len(self.messages(target_system, target_component, "COMMAND_ACK"))
        t_end = time.monotonic() + timeout_s
        confirmation = 0
        while time.monotonic() < t_end:
            self._conn.mav.command_long_send(target_system, target_component, command, confirmation, *p)
            confirmation = min(confirmation + 1, 255)
            t_try = time.monotonic() + 0.5
            while time.monotonic() < min(t_try, t_end):
                acks = self.messages(target_system, target_component, "COMMAND_ACK")[seen:]
                for a in acks:
                    if a.command == command:
                        return int(a.result)
                time.sleep(0.02)
        return None

    def upload_mission(
        self,
        target_system: int,
        items: list[GcsMissionItem],
        home_item: bool = False,
        target_component: int = 1,
        timeout_s: float = 15.0,
    ) -> int | None:
        """Upload a mission (mission_type 0) as a GCS does: MISSION_COUNT, a MISSION_ITEM_INT for
        each MISSION_REQUEST(_INT), until the vehicle's MISSION_ACK; its MAV_MISSION_RESULT, None
        without one. ``home_item``: send a placeholder item 0 first, as QGroundControl and Mission
        Planner do for ArduPilot (whose item 0 is its home)."""
        sent = list(items)
        if home_item:
            sent.insert(0, GcsMissionItem(MAV_FRAME_GLOBAL, 16, 0, 0, 0))
        seen = len(self.messages(target_system, target_component))
        t_end = time.monotonic() + timeout_s
        next_count = 0.0
        answered = False
        while time.monotonic() < t_end:
            if not answered and time.monotonic() >= next_count:  # the count was lost: say it again
                self._conn.mav.mission_count_send(target_system, target_component, len(sent), 0)
                next_count = time.monotonic() + 1.0
            msgs = self.messages(target_system, target_component)
            for m in msgs[seen:]:
                seen += 1
                t = m.get_type()
                if getattr(m, "mission_type", 0) != 0 or getattr(m, "target_system", self.source_system) not in (
                    0,
                    self.source_system,
                ):
                    continue
                if t == "MISSION_ACK":
                    return int(m.type)
                if t in ("MISSION_REQUEST_INT", "MISSION_REQUEST") and 0 <= m.seq < len(sent):
                    answered = True
                    it = sent[m.seq]
                    self._conn.mav.mission_item_int_send(
                        target_system, target_component, m.seq, it.frame, it.command, 0, 1,
                        it.param1, it.param2, it.param3, it.param4,
                        round(it.lat_deg * 1e7), round(it.lon_deg * 1e7), it.alt_m, 0,
                    )  # fmt: skip
            time.sleep(0.02)
        return None


MAV_FRAME_GLOBAL = 0
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3


@dataclass(frozen=True, slots=True)
class GcsMissionItem:
    """One item of a plan as a GCS sends it (MISSION_ITEM_INT; position in degrees)."""

    frame: int
    command: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
