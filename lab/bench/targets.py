"""The benches' targets, declared once (issue 60's figures), and the judge ``companion bench
check`` applies: a figure past its limit fails the check. Each target names the bench that
measures it and the figure's key in that bench's result (a dotted path into nested dicts)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

BENCHES = ("ekf", "vision", "app")


@dataclass(frozen=True, slots=True)
class Target:
    bench: str  # one of BENCHES
    key: str  # the figure in the bench's result; dotted for nested dicts
    limit: float  # the figure must be <= limit
    unit: str
    description: str


TARGETS: tuple[Target, ...] = (
    Target("ekf", "predict_plus_aruco_us", 50.0, "us", "EKF predict + ArUco update, per camera frame"),
    Target("ekf", "update_aruco_us", 30.0, "us", "EKF ArUco (camera pose) update"),
    Target("ekf", "update_uwb_us", 30.0, "us", "EKF UWB position update"),
    Target("ekf", "update_sdk_us", 30.0, "us", "EKF autopilot (GPS pose) update"),
    Target("ekf", "update_sdk_position_us", 30.0, "us", "EKF autopilot position-only update"),
    Target("vision", "ours/raw", 0.25, "ratio", "our ROI detection + pose time over OpenCV's full-frame detection"),
    Target("app", "cpu.companion_total_pct", 15.0, "% of one core", "the whole companion, vision included"),
    Target("app", "cpu.non_vision_pct", 6.0, "% of one core", "the companion without vision"),
    Target("app", "peak_rss_mib", 150.0, "MiB", "the app's peak resident memory"),
    Target("app", "guidance_overruns_pct", 1.0, "%", "guidance ticks that missed their deadline"),
)


@dataclass(frozen=True, slots=True)
class Verdict:
    target: Target
    measured: float | None  # None: the bench's result has no such figure (fails)

    @property
    def ok(self) -> bool:
        m = self.measured
        return m is not None and math.isfinite(m) and m <= self.target.limit

    def line(self) -> str:
        t, m = self.target, self.measured
        got = "missing" if m is None else f"{m:.3g}"
        return (
            f"{t.bench:<7} {t.key:<26} {got:>9} <= {t.limit:g} {t.unit:<14} "
            f"{'ok' if self.ok else 'FAILED'}  ({t.description})"
        )


def figure(result: Mapping[str, Any], key: str) -> float | None:
    """The number at ``key`` (dotted) in a bench's result, None when absent or not a number."""
    node: Any = result
    for part in _split(key, result):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    if isinstance(node, bool) or not isinstance(node, int | float):
        return None
    return float(node)


def _split(key: str, result: Mapping[str, Any]) -> list[str]:
    # a key holding a '/' or a '.' of its own ("ours/raw") is taken whole when the result has it
    return [key] if key in result else key.split(".")


def judge(bench: str, result: Mapping[str, Any], targets: Sequence[Target] = TARGETS) -> list[Verdict]:
    """Each target of ``bench`` against the figure ``result`` holds."""
    if bench not in BENCHES:
        raise ValueError(f"bench {bench!r}: expected one of {', '.join(BENCHES)}")
    return [Verdict(t, figure(result, t.key)) for t in targets if t.bench == bench]
