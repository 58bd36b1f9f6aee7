"""The final descent's controller on its own section ([mission.descent])."""

from __future__ import annotations

import pytest

from companion.config import DescentConfig
from companion.guidance.descent import PrecisionDescent


def _still() -> tuple[float, float]:
    return (0.0, 0.0)


def test_the_descent_closes_the_error_with_its_gain_within_its_speed_limit():
    d = PrecisionDescent(DescentConfig(xy_gain_1_s=2.0, max_xy_speed_m_s=0.5), land_speed_m_s=0.5)
    near = d.command(0.1, -0.05, 2.0, 0.0, may_hold=False, velocity_xy=_still)
    assert (near.x_m_s, near.y_m_s) == pytest.approx((-0.2, 0.1))
    far = PrecisionDescent(DescentConfig(xy_gain_1_s=2.0, max_xy_speed_m_s=0.5), 0.5).command(
        3.0, 4.0, 2.0, 0.0, may_hold=False, velocity_xy=_still
    )
    assert (far.x_m_s, far.y_m_s) == pytest.approx((-0.3, -0.4))  # 0.5 m/s along the error
    assert far.accel_xy_m_s2 is None  # no feedforward by default


def test_below_the_touchdown_height_only_the_descent_at_land_speed_remains():
    d = PrecisionDescent(DescentConfig(touchdown_height_m=0.15), land_speed_m_s=0.7)
    c = d.command(0.3, 0.3, 0.1, 0.0, may_hold=False, velocity_xy=_still)
    assert (c.x_m_s, c.y_m_s) == (0.0, 0.0) and c.z_m_s == pytest.approx(-0.7)
