"""quat_to_rotmat on Python floats against its numpy form (quat_normalize, then the matrix):
the same floats, bit for bit, and the same refusal of a zero or non-finite quaternion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.geometry.rotations import quat_normalize, quat_to_rotmat


def _numpy_form(q: np.ndarray) -> np.ndarray:
    w, x, y, z = quat_normalize(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_quat_to_rotmat_equals_the_numpy_form_bit_for_bit() -> None:
    rng = np.random.default_rng(4)
    for scale in (1e-3, 1.0, 1e3):
        for _ in range(2000):
            q = rng.normal(size=4) * scale
            np.testing.assert_array_equal(quat_to_rotmat(q), _numpy_form(q))
    np.testing.assert_array_equal(quat_to_rotmat([-1.0, 0.0, 0.0, 0.0]), np.eye(3))  # w < 0 flipped


@pytest.mark.parametrize("q", [[0.0, 0.0, 0.0, 0.0], [math.nan, 0.0, 0.0, 1.0], [math.inf, 0.0, 0.0, 0.0]])
def test_quat_to_rotmat_refuses_what_quat_normalize_refuses(q: list[float]) -> None:
    with pytest.raises(ValueError, match="cannot normalise"):
        quat_to_rotmat(q)
