"""State estimation: the 12-state delivery EKF with its delayed-measurement buffer, the Madgwick
and complementary attitude filters, and the estimate type. How the sensors are fused is the
applications' business (``companion.delivery.fusion``, ``companion.dart.estimators``)."""

from companion.estimation.delayed import BufferEventKind, DelayedMeasurementBuffer
from companion.estimation.ekf import DeliveryEkf, EkfConfig, EkfSensor, EkfSnapshot, UpdateOutcome
from companion.estimation.types import StateEstimate

__all__ = [
    "BufferEventKind",
    "DelayedMeasurementBuffer",
    "DeliveryEkf",
    "EkfConfig",
    "EkfSensor",
    "EkfSnapshot",
    "StateEstimate",
    "UpdateOutcome",
]
