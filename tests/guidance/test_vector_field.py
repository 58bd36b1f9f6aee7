import math

import numpy as np
import pytest

from companion.guidance import DeliveryPath, PathGeometryError, VectorField

H, R, D = 45.0, 6.0, 100.0
V = (2.0, 3.0, 5.0, 2.5, 1.5)
path = DeliveryPath(H, R, D)
field = VectorField(path, V, k_f=1.0)

# one point on each section, with its sector and the expected tangent for s = +1 (eq 1, 17)
ON_CURVE = [
    ((-D, 0, 10.0), 1, (0, 0, 1)),  # climbing
    ((-D + R - R * math.cos(0.6), 0, H - R + R * math.sin(0.6)), 2, None),
    ((-50.0, 0, H), 3, (1, 0, 0)),  # cruising towards the pad
    ((-R + R * math.sin(0.6), 0, H - R + R * math.cos(0.6)), 4, None),
    ((0.0, 0, 10.0), 5, (0, 0, -1)),  # descending onto the pad
]


@pytest.mark.parametrize(("p", "sector", "tangent"), ON_CURVE)
def test_on_curve_field_is_tangent_with_reference_speed(p, sector, tangent):
    a1, a2, _, g2, k = path.alphas(p)
    assert k == sector
    assert abs(a1) < 1e-12 and abs(a2) < 1e-9  # alpha_2's zero set matches the section
    fs = field(p, s=1)
    assert math.isclose(np.linalg.norm(fs.velocity), V[sector - 1], rel_tol=1e-9)  # |F| = v_r
    assert abs(np.dot(fs.velocity, g2)) < 1e-9  # tangent: no component across the curve
    if tangent is not None:
        assert np.allclose(fs.velocity / V[sector - 1], tangent, atol=1e-9)


def test_arc_tangent_hand_computed():
    # top of arc 2 (x = -d + r, z = h): moving +x; bottom of arc 4 (x = 0, z = h - r): moving -z
    assert np.allclose(field((-D + R - 1e-9, 0, H - 1e-12), 1).velocity / V[2 - 1], [1, 0, 0], atol=1e-6)
    assert np.allclose(field((-1e-9, 0, H - R + 1e-9), 1).velocity / V[4 - 1], [0, 0, -1], atol=1e-6)


@pytest.mark.parametrize("p", [(-60, 30, 20), (-100, -8, 44), (5, 4, 2), (-30, 0, 60), (-97, 2, 40)])
def test_far_from_curve_points_towards_it(p):
    fs = field(p, s=1)
    _, _, g1, g2, _ = path.alphas(p)
    a1, a2, *_ = path.alphas(p)
    gradV = a1 * g1 + a2 * g2
    # dV/dt along F is negative: the field brings the vehicle closer to the curve
    assert np.dot(gradV, fs.velocity) < 0
    # far away the convergent term dominates: G -> -1
    far = field((-50, 500, 45), 1)
    assert np.dot(far.velocity / np.linalg.norm(far.velocity), [0, -1, 0]) > 0.99


def test_reversal_with_s_minus_one():
    for p, _, _ in ON_CURVE:
        assert np.allclose(field(p, s=-1).velocity, -field(p, s=1).velocity, atol=1e-9)
    # off the curve the convergent part is the same, the tangent flips
    p = (-50, 1.0, 46)
    f1, f2 = field(p, 1).velocity, field(p, -1).velocity
    assert np.allclose((f1 + f2) / 2, field(p, 1).velocity - (f1 - f2) / 2)
    assert f1[0] > 0 > f2[0]
    with pytest.raises(ValueError):
        field(p, s=0)


@pytest.mark.parametrize(
    ("a", "b"),
    [
        ((-D + 0.3, 0.2, H - R - 1e-6), (-D + 0.3, 0.2, H - R + 1e-6)),  # S1 | S2
        ((-D + R - 1e-6, 0.2, H + 0.3), (-D + R + 1e-6, 0.2, H + 0.3)),  # S2 | S3
        ((-R - 1e-6, -0.2, H - 0.3), (-R + 1e-6, -0.2, H - 0.3)),  # S3 | S4
        ((0.3, 0.1, H - R + 1e-6), (0.3, 0.1, H - R - 1e-6)),  # S4 | S5
    ],
)
def test_field_continuous_across_sector_boundaries_near_the_path(a, b):
    assert path.sector(a) != path.sector(b)
    fa, fb = field(a, 1), field(b, 1)
    # the speed reference v_i changes by design; the direction must not jump
    ua, ub = fa.velocity / np.linalg.norm(fa.velocity), fb.velocity / np.linalg.norm(fb.velocity)
    assert np.linalg.norm(ua - ub) < 1e-4
    assert math.isclose(fa.lyapunov, fb.lyapunov, abs_tol=1e-5)


def test_sectors_eq1():
    assert path.sector((-D, 0, 0)) == 1
    assert path.sector((-D + 1, 0, H)) == 2
    assert path.sector((-50, 0, H)) == 3
    assert path.sector((-1, 0, H)) == 4
    assert path.sector((0, 0, 1)) == 5
    assert path.sector((-D / 2 + 0.01, 0, 0)) == 5 and path.sector((-D / 2, 0, 0)) == 1


def test_sampled_path_lies_on_the_curve():
    pts = path.sample(0.5)
    assert max(path.distance_to_path(p) for p in pts) < 1e-6
    assert np.allclose(pts[0], (-D, 0, 0)) and np.allclose(pts[-1], (0, 0, 0))


@pytest.mark.parametrize(
    ("h", "r", "d", "msg"),
    [
        (45, 0, 100, "r = 0"),
        (45, 50, 100, "must be < height"),
        (45, 6, 10, ">= 2 r"),
        (45, float("nan"), 100, "finite"),
    ],
)
def test_impossible_geometry_is_refused(h, r, d, msg):
    with pytest.raises(PathGeometryError, match=msg):
        DeliveryPath(h, r, d)
