"""Rodrigues' formula and the smallest rotation onto z (companion.geometry.rotations), against
SciPy's Rotation (the reference they replace on the flight path) over drawn vectors."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from companion.geometry.rotations import align_to_z, rotvec_to_rotmat


def test_rodrigues_matches_scipy_and_is_a_rotation() -> None:
    rng = np.random.default_rng(60)
    for _ in range(2000):
        v = rng.normal(size=3) * rng.choice([1e-9, 1e-3, 0.5, 3.0])
        R = rotvec_to_rotmat(v)
        assert np.allclose(R, Rotation.from_rotvec(v).as_matrix(), atol=1e-14, rtol=0.0)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-14) and np.linalg.det(R) > 0.999999
    assert np.array_equal(rotvec_to_rotmat(np.zeros(3)), np.eye(3))


def test_align_to_z_takes_the_direction_onto_z_by_the_smallest_angle() -> None:
    rng = np.random.default_rng(61)
    z = np.array([0.0, 0.0, 1.0])
    for _ in range(2000):
        d = rng.normal(size=3)
        R = align_to_z(d)
        u = d / np.linalg.norm(d)
        assert np.allclose(R @ u, z, atol=1e-12)
        # the smallest rotation: its angle is the angle between the two
        angle = np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
        assert abs(angle - np.arccos(np.clip(u[2], -1.0, 1.0))) < 1e-7
        if u[2] > 0.0:  # the camera's case (a direction near the optical axis): as SciPy aligns it
            ref, _ = Rotation.align_vectors(z.reshape(1, 3), u.reshape(1, 3))
            assert np.allclose(R, ref.as_matrix(), atol=1e-12)
    assert np.array_equal(align_to_z([0.0, 0.0, 2.0]), np.eye(3))
    assert np.allclose(align_to_z([0.0, 0.0, -1.0]) @ [0.0, 0.0, -1.0], z)
