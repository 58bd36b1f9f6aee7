"""The estimation micro-benchmark returns timings for every part."""

from __future__ import annotations

import math

import pytest

from companion.dart.estimators import ESTIMATORS
from companion_lab.bench.dart import bench_estimation


def test_bench_estimation_reports_every_estimator() -> None:
    result = bench_estimation(60)
    assert result["n"] == 60
    keys = {"madgwick_update_us", "complementary_predict_us"}
    keys |= {f"{name}.{part}_us" for name in ESTIMATORS for part in ("imu", "vision")}
    assert keys <= set(result)
    for key in keys:
        assert math.isfinite(result[key]) and result[key] > 0.0
    with pytest.raises(ValueError):
        bench_estimation(5)
