"""The multilateration's lower-overhead calls against the numpy forms they replace: the same
LAPACK routines and reductions, so the same floats (bit for bit), on seeded random problems."""

from __future__ import annotations

import numpy as np
import pytest

from companion.uwb import linalg
from companion.uwb.models import TDOA, TWR, MeasurementModel, model_jacobian, model_residuals
from companion.uwb.solver import levenberg_marquardt, levenberg_marquardt_residuals


@pytest.mark.parametrize("n", [3, 4])
def test_solve_and_inv_equal_numpy_bit_for_bit(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(500):
        J = rng.normal(size=(6, n))
        M = J.T @ J
        g = rng.normal(size=n)
        solved = linalg.solve(M, -g)
        assert solved is not None
        np.testing.assert_array_equal(solved, np.linalg.solve(M, -g))
        inv = linalg.inv(M)
        assert inv is not None and inv.flags["C_CONTIGUOUS"]  # as numpy's (einsum sums by layout)
        np.testing.assert_array_equal(inv, np.linalg.inv(M))
    assert linalg.solve(np.zeros((n, n)), np.ones(n)) is None  # singular: np.linalg raises
    assert linalg.inv(np.ones((n, n))) is None


@pytest.mark.parametrize("rows", [3, 5, 9])
def test_lstsq_equals_numpy_bit_for_bit(rows: int) -> None:
    rng = np.random.default_rng(rows)
    for _ in range(300):
        A, b = rng.normal(size=(rows, 3)), rng.normal(size=rows)
        x, rank = linalg.lstsq(A, b)
        x_ref, _, rank_ref, _ = np.linalg.lstsq(A, b, rcond=None)
        np.testing.assert_array_equal(x, x_ref)
        assert rank == rank_ref
    A = np.ones((rows, 3))  # rank 1
    assert linalg.lstsq(A, np.ones(rows))[1] == np.linalg.lstsq(A, np.ones(rows), rcond=None)[2]


@pytest.mark.parametrize("model", [TWR, TDOA], ids=lambda m: m.name)
def test_levenberg_marquardt_residuals_and_jacobian_equal_the_model_functions(model: MeasurementModel) -> None:
    """The LM's residuals at its solution are model_residuals there, and its Jacobian (from the
    residuals' intermediates) is model_jacobian, bit for bit."""
    rng = np.random.default_rng(11)
    for _ in range(100):
        anchors = rng.uniform(-5, 5, (6, 3))
        x = rng.uniform(-3, 3, 3)
        obs = np.sqrt(np.sum((x - anchors) ** 2, axis=1)) + rng.normal(0, 0.05, 6)
        theta0 = np.r_[x + rng.normal(0, 0.5, 3), [0.3] * (model.n_unknowns - 3)]
        theta, cost, r = levenberg_marquardt_residuals(theta0, anchors, obs, model, 30, 1e-7)
        np.testing.assert_array_equal(r, model_residuals(theta, anchors, obs, model))
        assert cost == float(r @ r)
        t2, c2 = levenberg_marquardt(theta0, anchors, obs, model, 30, 1e-7)
        np.testing.assert_array_equal(t2, theta)
        assert c2 == cost
        diff = theta[:3] - anchors
        J = model.jacobian_of(diff, np.sqrt(np.sum(diff**2, axis=1)))
        np.testing.assert_array_equal(J, model_jacobian(theta, anchors, model))
