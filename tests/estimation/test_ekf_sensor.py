"""The EKF's sensors and the delayed buffer's events are enums; the names they give the counters
(read by tests, written to campaign JSON as the fusion's outcomes) are the enums' values, as
the string keys were before."""

from __future__ import annotations

import math

import numpy as np

from companion.estimation.delayed import BufferEventKind, DelayedMeasurementBuffer
from companion.estimation.ekf import SENSORS, DeliveryEkf, EkfConfig, EkfSensor, UpdateOutcome
from companion.geometry import Transform


def test_the_sensors_and_their_order() -> None:
    assert [s.value for s in SENSORS] == ["sdk", "aruco", "uwb"]
    assert tuple(EkfSensor) == SENSORS


def test_the_counters_keep_their_names_and_order() -> None:
    outcomes = [
        "accepted",
        "rejected_nonfinite",
        "rejected_gate",
        "rejected_height",
        "rejected_numerical",
        "rejected_too_old",
        "rejected_uninitialized",
    ]
    assert [o.value for o in UpdateOutcome] == outcomes
    expected = ["input.nonfinite", "predict.bad_dt", "covariance.repairs"]
    for s in ("sdk", "aruco", "uwb"):
        expected += [f"{s}.{o}" for o in outcomes] + [f"{s}.gate_resets"]
    assert list(DeliveryEkf().counters) == expected


def test_the_buffer_events_name_the_ekf_sensors() -> None:
    assert BufferEventKind.INPUT.value == "input"
    assert {k.value for k in BufferEventKind} - {"input"} == {s.value for s in EkfSensor}


class _Fix:
    def __init__(self, t: float) -> None:
        self.time_s, self.x_m, self.y_m, self.z_m, self.pdop = t, 0.0, 0.0, -5.0, 1.0


def test_counts_are_kept_per_sensor_under_the_values_names() -> None:
    ekf = DeliveryEkf(EkfConfig(), x0=np.zeros(12))
    assert ekf.update_uwb(_Fix(0.0), Transform.identity()) is UpdateOutcome.ACCEPTED
    assert ekf.update_sdk([math.nan, 0.0, 0.0]) is UpdateOutcome.REJECTED_NONFINITE
    assert ekf.counters["uwb.accepted"] == 1 and ekf.counters["sdk.rejected_nonfinite"] == 1
    assert set(ekf.consecutive_rejections) == set(EkfSensor)
    buf = DelayedMeasurementBuffer(DeliveryEkf(EkfConfig(), x0=np.zeros(12)), 10.0, history_s=0.5)
    buf.predict(11.0, np.zeros(6))
    assert buf.update_uwb(_Fix(10.2), Transform.identity()) is UpdateOutcome.REJECTED_TOO_OLD
    assert buf.update_sdk(10.1, [0.0, 0.0, 0.0]) is UpdateOutcome.REJECTED_TOO_OLD
    assert buf.counters.extra == {"uwb.rejected_too_old": 1, "sdk.rejected_too_old": 1}
