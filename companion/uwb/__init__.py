"""UWB positioning (delivery section 4.2.2): anchor layouts and robust multilateration (TDoA,
delivery eqs 2-4, and two-way ranging as a DWM1001 in PANS mode reports it)."""

from companion.config import MultilaterationConfig
from companion.uwb.anchors import (
    DWM1001_MAX_RANGE_M,
    AnchorLayout,
    AnchorLayoutError,
    anchor_frame_to_ned,
    load_anchor_layout,
)
from companion.uwb.measurements import (
    MultilaterationCounters,
    RejectReason,
    TdoaMeasurement,
    TwrMeasurement,
    UwbFix,
    UwbRejection,
)
from companion.uwb.models import TDOA, TWR, MeasurementModel
from companion.uwb.multilateration import Multilaterator, solve_tdoa, solve_twr
from companion.uwb.solver import dilutions_of_precision

__all__ = [
    "DWM1001_MAX_RANGE_M",
    "TDOA",
    "TWR",
    "AnchorLayout",
    "AnchorLayoutError",
    "MeasurementModel",
    "MultilaterationConfig",
    "MultilaterationCounters",
    "Multilaterator",
    "RejectReason",
    "TdoaMeasurement",
    "TwrMeasurement",
    "UwbFix",
    "UwbRejection",
    "anchor_frame_to_ned",
    "dilutions_of_precision",
    "load_anchor_layout",
    "solve_tdoa",
    "solve_twr",
]
