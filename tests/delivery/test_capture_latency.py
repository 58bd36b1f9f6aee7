"""The frame's exposure time for the fusion (companion.delivery.capture_latency): configured,
the driver's stamp, the measured latency; stamps that cannot be right."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from companion.delivery.capture_latency import CameraTime, CaptureLatency, CaptureLatencyError
from companion.plugin_api import Frame

IMG = np.zeros((2, 2), np.uint8)
CONFIGURED_S = 0.05


def frame(i: int, capture_s: float | None, arrival_s: float | None) -> Frame:
    t = (arrival_s if arrival_s is not None else 0.0) - CONFIGURED_S
    return Frame(t, IMG, i, capture_time_s=capture_s, arrival_time_s=arrival_s)


def test_configured_mode_is_the_plugins_time_as_before():
    cl = CaptureLatency("configured", CONFIGURED_S)
    f = frame(1, capture_s=0.5, arrival_s=1.0)
    assert cl.exposure_time_s(f, 2.0) == f.time_s
    assert cl.measured == 0 and cl.estimate is None
    plain = Frame(0.25, IMG, 2)  # a plugin of api version 1 that knows nothing of stamps
    assert cl.exposure_time_s(plain, 2.0) == 0.25


def test_driver_mode_takes_the_stamp_and_measures_the_latency():
    rng = np.random.default_rng(3)
    cl = CaptureLatency(CameraTime.DRIVER, CONFIGURED_S, window=32, min_samples=8)
    true_latency_s = 0.13  # 80 ms the configuration does not know about
    for i in range(40):
        cap = 10.0 + i / 30.0
        arr = cap + true_latency_s + float(rng.uniform(0.0, 0.004))
        assert cl.exposure_time_s(frame(i, cap, arr), arr + 0.001) == cap
    est = cl.estimate
    assert est is not None and est.n == 32
    assert est.median_s == pytest.approx(0.132, abs=0.0015)
    assert 0.0 < est.jitter_s < 0.003 and est.min_s >= 0.13 and est.max_s <= 0.134
    assert cl.summary()["median_ms"] == pytest.approx(132.0, abs=1.5)


def test_measured_mode_takes_arrival_minus_the_median():
    cl = CaptureLatency("measured", CONFIGURED_S, window=16, min_samples=4)
    outs = []
    for i in range(10):
        cap = 1.0 + 0.1 * i
        # a stamp jittering by +-5 ms around the true exposure, a constant 80 ms to arrival
        jitter = 0.005 if i % 2 else -0.005
        outs.append(cl.exposure_time_s(frame(i, cap + jitter, cap + 0.08), 99.0))
    # before 4 frames measured it: the stamp; after: arrival - median (0.08), the jitter gone
    assert outs[0] == pytest.approx(1.0 - 0.005)
    assert all(o == pytest.approx(1.0 + 0.1 * i, abs=0.0051) for i, o in enumerate(outs[4:], 4))
    assert cl.estimate is not None and cl.estimate.median_s == pytest.approx(0.08, abs=0.0051)


def test_the_arrival_is_the_read_time_when_the_frame_does_not_say():
    cl = CaptureLatency("driver", CONFIGURED_S, min_samples=1)
    cl.exposure_time_s(frame(0, 3.0, None), 3.09)
    assert cl.estimate is not None and cl.estimate.median_s == pytest.approx(0.09)


@pytest.mark.parametrize(
    ("capture_s", "arrival_s"),
    [(math.nan, 1.0), (math.inf, 1.0), (1.5, 1.0), (-5.0, 1.0)],  # NaN, inf, after arrival, 6 s before
)
def test_an_impossible_stamp_falls_back_to_the_configured_latency(capture_s, arrival_s, caplog):
    cl = CaptureLatency("driver", CONFIGURED_S, max_latency_s=1.0)
    f = frame(7, capture_s, arrival_s)
    with caplog.at_level(logging.WARNING, logger="companion.delivery.capture_latency"):
        assert cl.exposure_time_s(f, 2.0) == f.time_s
    assert cl.rejected == 1 and cl.measured == 0
    assert "configured latency instead" in caplog.text


def test_unstamped_frames_keep_the_configured_latency():
    cl = CaptureLatency("measured", CONFIGURED_S)
    f = Frame(4.0, IMG, 1)
    assert cl.exposure_time_s(f, 4.05) == 4.0
    assert cl.unstamped == 1


def test_disagreement_with_the_configuration_is_said_once(caplog):
    cl = CaptureLatency("driver", CONFIGURED_S, min_samples=2)
    with caplog.at_level(logging.INFO, logger="companion.delivery.capture_latency"):
        for i in range(5):
            cl.exposure_time_s(frame(i, float(i), i + 0.08), 0.0)
    assert caplog.text.count("landing.camera_latency_s says 50.0 ms") == 1
    assert "median 80.0 ms" in caplog.text


@pytest.mark.parametrize(
    "kwargs",
    [
        {"mode": "guess"},
        {"configured_latency_s": -0.1},
        {"configured_latency_s": math.nan},
        {"window": 0},
        {"min_samples": 100},
        {"max_latency_s": 0.0},
    ],
)
def test_bad_settings_are_named(kwargs):
    args = {"mode": "driver", "configured_latency_s": 0.05} | kwargs
    with pytest.raises(CaptureLatencyError):
        CaptureLatency(**args)
