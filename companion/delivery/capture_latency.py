"""The time a camera frame was exposed, as the landing fusion takes it (``landing.camera_time``,
docs/clock.md).

A frame reaches the fusion ``latency`` after its exposure, and the fusion replays the frame's
observation against the autopilot's state *at the exposure* (the delayed-measurement buffer,
:mod:`companion.estimation.delayed`): a latency mistaken by ``d`` puts the observation ``d`` in
the past of where it belongs, and the pad ``v x d`` off at the descent speed ``v``.

- ``configured``: the plugin's ``Frame.time_s`` (its arrival minus ``landing.camera_latency_s``),
  as before this module existed (the default; the same floats);
- ``driver``: the driver's own capture stamp (``Frame.capture_time_s``, on the shell's monotonic
  clock) where the frame carries a plausible one, else ``time_s``;
- ``measured``: the arrival minus the *measured* latency, the robust median of ``arrival -
  capture`` over the last frames (a stamp's own jitter, a driver's rounding to the millisecond,
  averaged out), once :attr:`CaptureLatency.min_samples` frames measured it; before, as ``driver``.

In the last two modes every frame carrying both stamps is measured; a stamp that is not finite,
lies after the arrival or more than ``max_latency_s`` before it is rejected (counted, said) and
the frame falls back to ``time_s``. The measured latency is logged when it settles and when it
moves by more than :data:`LOG_STEP_S`, and said plainly when it disagrees with the configuration.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

LOG_STEP_S = 0.005  # the measured latency is logged again when its median moves this much
DISAGREE_S = 0.010  # measured and configured latencies further apart than this: a warning
MAD_TO_STD = 1.4826  # a normal distribution's standard deviation per median absolute deviation


class CameraTime(StrEnum):
    CONFIGURED = "configured"
    DRIVER = "driver"
    MEASURED = "measured"


class CaptureLatencyError(ValueError):
    """A bad setting of the capture-latency measurement."""


@dataclass(frozen=True, slots=True)
class LatencyEstimate:
    """The measured capture latency (arrival - capture) over the last ``n`` frames: its median,
    its jitter (1.4826 x the median absolute deviation: a standard deviation robust to outliers)
    and its range, seconds."""

    median_s: float
    jitter_s: float
    min_s: float
    max_s: float
    n: int


class CaptureLatency:
    """The exposure time the fusion uses for each frame, per ``mode`` (see the module)."""

    def __init__(
        self,
        mode: CameraTime | str,
        configured_latency_s: float,
        window: int = 64,
        min_samples: int = 8,
        max_latency_s: float = 1.0,
    ) -> None:
        try:
            self.mode = CameraTime(mode)
        except ValueError:
            raise CaptureLatencyError(
                f"camera_time = {mode!r}: expected one of {[m.value for m in CameraTime]}"
            ) from None
        if not (math.isfinite(configured_latency_s) and configured_latency_s >= 0.0):
            raise CaptureLatencyError(f"configured_latency_s = {configured_latency_s!r}: expected finite and >= 0")
        if window < 1 or not 1 <= min_samples <= window:
            raise CaptureLatencyError(f"window {window}, min_samples {min_samples}: need 1 <= min_samples <= window")
        if not (math.isfinite(max_latency_s) and max_latency_s > 0.0):
            raise CaptureLatencyError(f"max_latency_s = {max_latency_s!r}: expected finite and > 0")
        self.configured_latency_s = float(configured_latency_s)
        self.min_samples = min_samples
        self.max_latency_s = float(max_latency_s)
        self._latencies_s: deque[float] = deque(maxlen=window)
        self.measured = 0  # frames whose latency was measured
        self.rejected = 0  # frames whose capture stamp was implausible (fell back to time_s)
        self.unstamped = 0  # frames without a capture stamp (in driver / measured mode)
        self._logged_median_s: float | None = None
        self._disagreement_said = False

    @property
    def estimate(self) -> LatencyEstimate | None:
        """The measured latency, None before :attr:`min_samples` frames measured it."""
        if len(self._latencies_s) < self.min_samples:
            return None
        a = np.fromiter(self._latencies_s, dtype=float)
        med = float(np.median(a))
        return LatencyEstimate(
            med, MAD_TO_STD * float(np.median(np.abs(a - med))), float(a.min()), float(a.max()), int(a.size)
        )

    def exposure_time_s(self, frame: Any, now_s: float) -> float:
        """The exposure time of ``frame`` (a :class:`companion.plugin_api.Frame`) for the fusion;
        ``now_s``: the shell's clock as it read the frame (its arrival when the frame does not say)."""
        if self.mode is CameraTime.CONFIGURED:
            return frame.time_s  # type: ignore[no-any-return]  # the very object the plugin gave
        capture_s = getattr(frame, "capture_time_s", None)
        if capture_s is None:
            self.unstamped += 1
            return float(frame.time_s)
        arrival_s = getattr(frame, "arrival_time_s", None)
        arrival_s = now_s if arrival_s is None else arrival_s
        latency_s = arrival_s - capture_s
        if not (math.isfinite(latency_s) and 0.0 <= latency_s <= self.max_latency_s):
            self.rejected += 1
            if self.rejected in (1, 10) or self.rejected % 100 == 0:
                log.warning(
                    "camera frame %s: capture stamp %r s with arrival %r s (latency %r s) is not within "
                    "[0, %.3f] s; the frame is stamped with the configured latency instead (%d rejected so far)",
                    getattr(frame, "index", "?"),
                    capture_s,
                    arrival_s,
                    latency_s,
                    self.max_latency_s,
                    self.rejected,
                )
            return float(frame.time_s)
        self._latencies_s.append(latency_s)
        self.measured += 1
        est = self.estimate
        if est is not None:
            self._say(est)
        if self.mode is CameraTime.MEASURED and est is not None:
            return float(arrival_s - est.median_s)
        return float(capture_s)

    def _say(self, est: LatencyEstimate) -> None:
        if self._logged_median_s is None or abs(est.median_s - self._logged_median_s) > LOG_STEP_S:
            log.info(
                "camera capture latency measured: median %.1f ms, jitter %.1f ms, range %.1f-%.1f ms over %d frames "
                "(landing.camera_latency_s = %.1f ms)",
                1e3 * est.median_s,
                1e3 * est.jitter_s,
                1e3 * est.min_s,
                1e3 * est.max_s,
                est.n,
                1e3 * self.configured_latency_s,
            )
            self._logged_median_s = est.median_s
        if not self._disagreement_said and abs(est.median_s - self.configured_latency_s) > DISAGREE_S:
            self._disagreement_said = True
            log.warning(
                "the camera's frames arrive %.1f ms after capture, landing.camera_latency_s says %.1f ms: "
                "landing.camera_time = %s compensates the measured latency; set camera_latency_s = %.3f for "
                "frames without a driver stamp",
                1e3 * est.median_s,
                1e3 * self.configured_latency_s,
                self.mode.value,
                est.median_s,
            )

    def summary(self) -> dict[str, Any]:
        """The measurement for the run's logs: the mode, counts and the estimate (ms)."""
        est = self.estimate
        out: dict[str, Any] = {
            "mode": self.mode.value,
            "configured_ms": 1e3 * self.configured_latency_s,
            "measured": self.measured,
            "rejected": self.rejected,
            "unstamped": self.unstamped,
        }
        if est is not None:
            out |= {"median_ms": 1e3 * est.median_s, "jitter_ms": 1e3 * est.jitter_s, "n": est.n}
        return out
