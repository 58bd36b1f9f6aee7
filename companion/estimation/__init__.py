"""State estimation: the autopilot pass-through (GPS-only baseline), the 12-state delivery EKF
with its delayed-measurement buffer, and the Dart filters and estimators."""

from companion.estimation.delayed import DelayedMeasurementBuffer
from companion.estimation.ekf import DeliveryEkf, EkfConfig, EkfSnapshot, UpdateOutcome
from companion.estimation.passthrough import AutopilotPoseEstimator
from companion.estimation.types import StateEstimate

__all__ = [
    "AutopilotPoseEstimator",
    "DelayedMeasurementBuffer",
    "DeliveryEkf",
    "EkfConfig",
    "EkfSnapshot",
    "StateEstimate",
    "UpdateOutcome",
]
