"""State estimation: the autopilot pass-through (GPS-only baseline); later the 12-state EKF,
Madgwick, the complementary filter and the Dart estimators."""

from companion.estimation.passthrough import AutopilotPoseEstimator
from companion.estimation.types import StateEstimate

__all__ = ["AutopilotPoseEstimator", "StateEstimate"]
