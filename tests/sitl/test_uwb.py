"""The simulated UWB source: noise, NLOS, dropouts, range limit, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from companion.uwb.anchors import load_anchor_layout
from companion.uwb.measurements import UwbFix
from companion.uwb.multilateration import Multilaterator
from companion_plugins.dwm1001 import parse_lec_line
from companion_sitl.uwb import SimulatedUwb, UwbSimConfig, format_lec_line

LAYOUT = load_anchor_layout()
A = LAYOUT.positions_array()
P = np.array([0.3, -0.4, 3.0])


def test_noiseless_matches_geometry() -> None:
    sim = SimulatedUwb(LAYOUT, UwbSimConfig(range_sigma_m=0.0), seed=1)
    twr = sim.twr(2.5, P)
    assert twr.time_s == 2.5 and twr.anchor_ids == LAYOUT.anchor_ids
    np.testing.assert_allclose(twr.ranges_m, np.linalg.norm(A - P, axis=1), atol=1e-12)
    tdoa = sim.tdoa(2.5, P)
    assert tdoa is not None and tdoa.base_anchor_id == LAYOUT.base_anchor_id
    d = np.linalg.norm(A - P, axis=1)
    np.testing.assert_allclose(tdoa.range_differences_m, d[1:] - d[0], atol=1e-12)  # delivery eq 2


def test_deterministic_for_a_seed() -> None:
    cfg = UwbSimConfig(range_sigma_m=0.1, nlos_probability=0.2, dropout_probability=0.1)
    a = [SimulatedUwb(LAYOUT, cfg, seed=42).twr(0.0, P) for _ in range(2)]
    assert a[0] == a[1]
    s1, s2 = SimulatedUwb(LAYOUT, cfg, seed=np.random.default_rng(5)), SimulatedUwb(LAYOUT, cfg, seed=5)
    assert [s1.twr(t, P) for t in range(5)] == [s2.twr(t, P) for t in range(5)]
    assert SimulatedUwb(LAYOUT, cfg, seed=43).twr(0.0, P) != a[0]


def test_gaussian_noise_statistics() -> None:
    sim = SimulatedUwb(LAYOUT, UwbSimConfig(range_sigma_m=0.07), seed=3)
    true = np.linalg.norm(A - P, axis=1)
    err = np.array([np.array(sim.twr(0.0, P).ranges_m) - true for _ in range(3000)])
    assert abs(err.mean()) < 0.005
    assert err.std() == pytest.approx(0.07, rel=0.05)


def test_nlos_is_a_positive_bias_with_the_configured_probability() -> None:
    cfg = UwbSimConfig(range_sigma_m=0.01, nlos_probability=0.2, nlos_bias_mean_m=0.8)
    sim = SimulatedUwb(LAYOUT, cfg, seed=4)
    true = np.linalg.norm(A - P, axis=1)
    n_nlos, n_total, biases = 0, 0, []
    for _ in range(2000):
        m = sim.twr(0.0, P)
        err = np.array(m.ranges_m) - true
        nlos = np.array([a in sim.last_nlos_ids for a in m.anchor_ids])
        assert np.all(err[~nlos] < 0.06)
        biases.extend(err[nlos])
        n_nlos += int(nlos.sum())
        n_total += len(nlos)
    assert n_nlos / n_total == pytest.approx(0.2, abs=0.02)
    assert min(biases) > -0.05  # positive (beyond noise)
    assert np.mean(biases) == pytest.approx(0.8, rel=0.1)


def test_dropouts_and_range_limit() -> None:
    sim = SimulatedUwb(LAYOUT, UwbSimConfig(dropout_probability=0.3), seed=6)
    counts = [len(sim.twr(0.0, P).anchor_ids) for _ in range(2000)]
    assert np.mean(counts) == pytest.approx(0.7 * len(A), rel=0.05)
    far = np.array([6.5, 2.0, 2.5])
    sim = SimulatedUwb(LAYOUT, UwbSimConfig(range_sigma_m=0.0), seed=6)
    m = sim.twr(0.0, far)
    d = np.linalg.norm(A - far, axis=1)
    assert set(m.anchor_ids) == {a for a, di in zip(LAYOUT.anchor_ids, d, strict=True) if di <= 10.0}
    assert set(sim.last_out_of_range_ids) == {a for a, di in zip(LAYOUT.anchor_ids, d, strict=True) if di > 10.0}
    assert all(r <= 10.0 for r in m.ranges_m)
    assert sim.twr(0.0, [0.0, 0.0, 40.0]).anchor_ids == ()
    assert sim.tdoa(0.0, [0.0, 0.0, 40.0]) is None  # base anchor not heard


def test_simulated_data_solves_to_the_truth() -> None:
    sim = SimulatedUwb(LAYOUT, UwbSimConfig(range_sigma_m=0.03), seed=7)
    m = Multilaterator(LAYOUT)
    for _ in range(20):
        f = m.solve_twr(sim.twr(0.0, P))
        assert isinstance(f, UwbFix) and np.linalg.norm(f.position_m - P) < 0.2
        tdoa = sim.tdoa(0.0, P)
        assert tdoa is not None
        g = m.solve_tdoa(tdoa)
        assert isinstance(g, UwbFix) and np.linalg.norm(g.position_m - P) < 0.4


def test_lec_line_round_trip() -> None:
    sim = SimulatedUwb(LAYOUT, UwbSimConfig(range_sigma_m=0.0), seed=8)
    m = sim.twr(1.0, P)
    line = format_lec_line(LAYOUT, m, position_m=P, quality_factor=77)
    r = parse_lec_line(line)
    assert r is not None and len(r.anchors) == 4 and r.quality_factor == 77
    assert [a.anchor_id for a in r.anchors] == list(m.anchor_ids[:4])
    np.testing.assert_allclose([a.distance_m for a in r.anchors], m.ranges_m[:4], atol=0.005)
    assert r.position_m == pytest.approx(tuple(P), abs=0.005)


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="nlos_probability"):
        UwbSimConfig(nlos_probability=1.5)
    with pytest.raises(ValueError, match="range_sigma_m"):
        UwbSimConfig(range_sigma_m=-0.1)
    with pytest.raises(ValueError, match="max_range_m"):
        UwbSimConfig(max_range_m=0.0)
