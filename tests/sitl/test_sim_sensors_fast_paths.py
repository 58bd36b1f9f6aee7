"""Fast paths of the embedded simulator that must not change what it computes: the Gauss-Markov
coefficients kept between steps, and the camera source's scan for the newest ready exposure."""

from __future__ import annotations

import math

import numpy as np

from companion.geometry import Transform
from companion.vision.camera import load_default_camera
from companion_sitl.camera import SimulatedCamera
from companion_sitl.landing_sensors import SimCameraSource
from companion_sitl.vehicle import _GaussMarkov


def test_gauss_markov_step_equals_the_formula_bit_for_bit_when_dt_or_parameters_change() -> None:
    rng = np.random.default_rng(2)
    g = _GaussMarkov(0.7, 12.0, 0.3)
    x = g.x
    for k in range(300):
        dt = 0.005 if k < 100 else (0.002 if k < 200 else float(rng.uniform(1e-4, 0.5)))
        if k == 150:
            g.sigma = 1.9  # a changed parameter is not served from the kept coefficients
        if k == 250:
            g.tau = 3.0
        n = float(rng.standard_normal())
        a = math.exp(-dt / g.tau)
        x = a * x + g.sigma * math.sqrt(1.0 - a * a) * n
        assert g.step(dt, n) == x


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t


def test_camera_source_reads_the_newest_ready_unread_exposure() -> None:
    cam = SimulatedCamera(load_default_camera(), seed=0)
    src = SimCameraSource(vehicle=None, camera=cam, rate_hz=30.0, latency_s=0.05)  # type: ignore[arg-type]
    clock = _Clock()
    src._clock = clock  # type: ignore[assignment]
    above = Transform.from_euler([0.0, 0.0, -5.0], 0.0, 0.0, 0.0)  # over the pad: in view
    beside = Transform.from_euler([40.0, 0.0, -5.0], 0.0, 0.0, 0.0)  # the pad far out of view
    for k in range(10):
        src._poses.append((k / 30, beside if k == 7 else above))
    clock.t = 0.04
    assert src.read() is None  # nothing exposed 50 ms ago yet
    clock.t = 0.12  # exposures 0..2 are ready: the newest, 2, is read, 0 and 1 are dropped
    f = src.read()
    assert f is not None and f.time_s == 2 / 30 and src.rendered == 1
    assert src.read() is None  # nothing new is ready
    clock.t = 0.30  # 3..7 ready: the newest, 7, does not show the pad
    assert src.read() is None and src.out_of_view == 1 and src.rendered == 1
    clock.t = 0.32  # 8 ready
    f = src.read()
    assert f is not None and f.time_s == 8 / 30 and f.index == 2
    clock.t = 10.0
    f = src.read()
    assert f is not None and f.time_s == 9 / 30
    assert src.read() is None
