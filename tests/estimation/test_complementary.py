"""Complementary filter (dart eq 14)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.estimation.complementary import ComplementaryConfig, ComplementaryFilter


def test_eq14_one_step_by_hand() -> None:
    # lambda = 0.9, Phi_hat = (0.1, -0.2, 0.0), T = 0.01 s, Omega = (1, 2, -3) rad/s,
    # Phi (vision) = (0.3, 0.0, 0.05):
    #   roll : 0.9 (0.1 + 0.01)  + 0.1 * 0.3  = 0.099 + 0.03   = 0.129
    #   pitch: 0.9 (-0.2 + 0.02) + 0.1 * 0.0  = -0.162
    #   yaw  : 0.9 (0.0 - 0.03)  + 0.1 * 0.05 = -0.027 + 0.005 = -0.022
    cf = ComplementaryFilter(ComplementaryConfig(lam=0.9))
    cf.reset((0.1, -0.2, 0.0), time_s=1.0)
    out = cf.update(1.01, (1.0, 2.0, -3.0), (0.3, 0.0, 0.05))
    assert out == pytest.approx((0.129, -0.162, -0.022), abs=1e-12)


def test_blends_angles_the_short_way_round() -> None:
    # Phi_hat = 3.1, Phi = -3.1: the two are 0.083 rad apart across +-pi.
    # 3.1 + 0.1 * wrap(-3.1 - 3.1) = 3.1 + 0.1 * 0.0832 = 3.10832 (not 0.9*3.1 - 0.31 = 2.48)
    cf = ComplementaryFilter(ComplementaryConfig(lam=0.9))
    cf.reset((3.1, 0.0, 0.0), time_s=0.0)
    cf.correct((-3.1, 0.0, 0.0))
    assert cf.angles[0] == pytest.approx(3.1 + 0.1 * (2 * math.pi - 6.2), abs=1e-12)


def test_converges_geometrically_to_the_measurement() -> None:
    cf = ComplementaryFilter(ComplementaryConfig(lam=0.8))
    cf.reset((0.0, 0.0, 0.0), time_s=0.0)
    for k in range(1, 11):
        cf.update(k * 0.01, (0.0, 0.0, 0.0), (1.0, -1.0, 0.5))
    # error after k steps: lambda^k times the initial error
    assert cf.angles == pytest.approx((1 - 0.8**10, -(1 - 0.8**10), 0.5 * (1 - 0.8**10)))


def test_gyro_bias_steady_state_error() -> None:
    # with a constant gyro bias b and a constant true angle, eq 14 settles where
    # e = lambda (e + T b)  ->  e = lambda T b / (1 - lambda) = 0.9 * 0.01 * 0.1 / 0.1 = 0.009
    cf = ComplementaryFilter(ComplementaryConfig(lam=0.9))
    cf.reset((0.0, 0.0, 0.0), time_s=0.0)
    for k in range(1, 400):
        cf.update(k * 0.01, (0.1, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert cf.angles[0] == pytest.approx(0.009, abs=1e-9)


def test_multirate_predict_then_correct_is_eq14_over_the_vision_period() -> None:
    # 7 gyro samples of 5 ms then one vision frame: T Omega of eq 14 is the integrated increment
    cf = ComplementaryFilter(ComplementaryConfig(lam=0.95))
    cf.reset((0.2, 0.0, 0.0), time_s=0.0)
    for k in range(1, 8):
        cf.predict(k * 0.005, (0.4, 0.0, 0.0))
    cf.correct((0.25, 0.0, 0.0))
    assert cf.angles[0] == pytest.approx(0.95 * (0.2 + 0.035 * 0.4) + 0.05 * 0.25)


def test_extremes_and_noise_reduction() -> None:
    gyro_only = ComplementaryFilter(ComplementaryConfig(lam=1.0))
    gyro_only.reset((0.0, 0.0, 0.0), 0.0)
    gyro_only.update(0.1, (1.0, 0.0, 0.0), (5.0, 5.0, 5.0))
    assert gyro_only.angles == pytest.approx((0.1, 0.0, 0.0))
    vision_only = ComplementaryFilter(ComplementaryConfig(lam=0.0))
    vision_only.reset((0.0, 0.0, 0.0), 0.0)
    vision_only.update(0.1, (1.0, 0.0, 0.0), (0.5, 0.4, 0.3))
    assert vision_only.angles == pytest.approx((0.5, 0.4, 0.3))

    # noisy vision + exact gyro: the filtered angle is much less noisy than the vision
    rng = np.random.default_rng(7)
    cf = ComplementaryFilter(ComplementaryConfig(lam=0.95))
    cf.reset((0.0, 0.0, 0.0), 0.0)
    errs, raw = [], []
    for k in range(1, 600):
        t = k * 0.01
        truth = 0.3 * math.sin(t)
        meas = truth + rng.normal(0.0, 0.05)
        cf.update(t, (0.3 * math.cos(t - 0.005), 0.0, 0.0), (meas, 0.0, 0.0))
        if k > 100:
            errs.append(cf.angles[0] - truth)
            raw.append(meas - truth)
    assert np.std(errs) < 0.35 * np.std(raw)


def test_rejects_non_finite_and_initialises_on_first_measurement() -> None:
    cf = ComplementaryFilter()
    assert not cf.initialised
    assert cf.predict(0.0, (1.0, 0.0, 0.0))
    assert cf.predict(0.01, (1.0, 0.0, 0.0))
    assert cf.angles == (0.0, 0.0, 0.0)  # nothing to integrate before a measurement
    assert cf.correct((0.1, 0.2, 0.3))
    assert cf.angles == (0.1, 0.2, 0.3)
    assert not cf.correct((math.nan, 0.0, 0.0))
    assert not cf.predict(0.02, (math.nan, 0.0, 0.0))
    assert not cf.predict(0.005, (0.0, 0.0, 0.0))  # time went backwards
    assert cf.rejected == 3


def test_lambda_from_time_constant() -> None:
    assert ComplementaryConfig.from_time_constant(0.9, 0.1).lam == pytest.approx(0.9)
    with pytest.raises(ValueError):
        ComplementaryConfig(lam=1.2)
