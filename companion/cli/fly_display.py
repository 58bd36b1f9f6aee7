"""What `companion fly` shows the operator on a terminal, as `companion demo` does: the phase, the
distance still to fly and the progress through the mission while it flies, then the summary
table (``--json`` prints one JSON line instead, for scripts)."""

from __future__ import annotations

import math
from typing import Any

from companion.delivery.mission import MissionSummary
from companion.units import format_m

PHASES = (
    "preflight",
    "arming",
    "takeoff",
    "outbound",
    "landing_pad",
    "release",
    "takeoff_return",
    "inbound",
    "landing_home",
    "done",
)


def distance_to_go_m(shell: Any) -> float | None:
    """Horizontal distance from the estimate to where the vehicle is going: the pad until the
    parcel is delivered (or the way home is taken), then home: where the outbound started, which
    the return flies to. Not the autopilot's home: ArduCopter and PX4 move theirs to where they
    arm, the pad for the way back. None before the path is planned."""
    m, e = shell.mission, shell.estimate
    if e is None or m.pad_ned is None:
        return None
    if m.summary.delivered or m.returning:
        if m.start_ned is None:
            return None
        target = (float(m.start_ned[0]), float(m.start_ned[1]))
    else:
        target = (float(m.pad_ned[0]), float(m.pad_ned[1]))
    return math.hypot(e.north_m - target[0], e.east_m - target[1])


def progress_fields(shell: Any, out: Any) -> dict[str, Any]:
    """The progress row of one guidance tick: phase, phases done, distance to go, height."""
    ph = out.phase.value
    d = distance_to_go_m(shell)
    e = shell.estimate
    where = []
    if d is not None:
        where.append(f"{format_m(d)} to go")
    if e is not None:
        where.append(f"alt {-e.down_m:5.1f} m")
    if out.sector:
        where.append(f"S{out.sector}")
    return {
        "description": ph,
        "completed": PHASES.index(ph) if ph in PHASES else None,
        "where": "  ".join(where),
    }


def summary_rows(summary: MissionSummary, shell: Any | None, run_dir: Any) -> list[tuple[str, str]]:
    """The table printed at the end of a flight."""
    s = summary
    rows: list[tuple[str, str]] = []
    if s.takeoff_time_s is not None and s.end_time_s is not None:
        rows.append(("flight time", f"{s.end_time_s - s.takeoff_time_s:.1f} s"))
    if shell is not None:
        pad = shell.mission.pad_ned
        if s.pad_touchdown_ned is not None and pad is not None:
            off = math.hypot(s.pad_touchdown_ned[0] - pad[0], s.pad_touchdown_ned[1] - pad[1])
            rows.append(("touchdown from the configured pad (estimate)", format_m(off)))
        home = shell.mission.start_ned  # where the outbound started (distance_to_go_m)
        if s.home_touchdown_ned is not None and home is not None:
            off = math.hypot(s.home_touchdown_ned[0] - home[0], s.home_touchdown_ned[1] - home[1])
            rows.append(("touchdown from home (estimate)", format_m(off)))
        st = shell.stats
        rows.append(("setpoints sent / clamped", f"{st.setpoints_sent} / {st.setpoints_clamped}"))
        rows.append(("autopilot requests / failed", f"{st.requests} / {st.requests_failed}"))
        rows.append(("mission events", str(len(shell.events))))
        if shell.ground_commands:
            rows.append(("commands from the ground", "; ".join(f"{k}: {r}" for k, r in shell.ground_commands)))
        if shell.made_ready:
            rows.append(("autopilot mode for the next mission", "; ".join(shell.made_ready)))
    rows.append(("run folder", f"{run_dir}  (flight.tlog, per-stream CSVs)"))
    return rows


def headline(summary: MissionSummary) -> str:
    s = summary
    return (
        f"[bold]{'DELIVERED' if s.delivered else 'NOT DELIVERED'}[/]"
        + (", returned home" if s.returned else "")
        + (f"  [red]{s.failure}[/]" if s.failure else "")
    )
