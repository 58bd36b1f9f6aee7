"""Guidance: the delivery path and sectors, the vector field, the velocity setpoint and its limits."""

from companion.guidance.limits import ClampResult, clamp_velocity
from companion.guidance.path import DeliveryPath, PathGeometryError
from companion.guidance.setpoint import VelocitySetpoint
from companion.guidance.vector_field import FieldSample, VectorField

__all__ = [
    "ClampResult",
    "DeliveryPath",
    "FieldSample",
    "PathGeometryError",
    "VectorField",
    "VelocitySetpoint",
    "clamp_velocity",
]
