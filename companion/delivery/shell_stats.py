"""What the delivery shell counts as it flies (``DeliveryShell.stats``): its loops' ticks and
overruns, the setpoints, the requests, how the camera is read. Each of the shell's parts adds to
the one instance the shell owns; benches and tests read it."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ShellStats:
    guidance_ticks: int = 0
    guidance_overruns: int = 0
    setpoint_overruns: int = 0
    setpoints_sent: int = 0
    setpoints_clamped: int = 0
    stream_stops: int = 0
    requests: int = 0
    requests_failed: int = 0
    # how the camera is read: "" (no camera task), "frame listener", "polled"
    camera_read: str = ""
    frames_notified: int = 0  # wake-ups of the camera task by its frame listener
    frames_paced: int = 0  # frames not read: the detector's CPU budget (runtime.vision_cpu_budget) was spent
    realtime: str = ""  # runtime.realtime_priority: "SCHED_RR <priority>", "refused: <why>", "" (not asked)
