"""The Dart's component configs are schema sections of the Dart file (companion.param_kinds):
declared once with unit, limits and description, taken by the components as they are, shown by
``params show`` and checked by ``params check``; their defaults are the former constants."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from companion.cli.main import main
from companion.dart.control import DartControllerConfig, PidGains
from companion.dart.estimators import DartEstimatorConfig, camera_mount, wall_marker
from companion.dart.mission import DartParamsError
from companion.dart.mixer import AttitudeMapConfig, RcMixer, RcMixerConfig, attitude_setpoint
from companion.dart.params import (
    DartControlGains,
    DartRuntimeConfig,
    controller_config,
    load_dart_flight_params,
)
from companion.dart.shell import estimator_config
from companion.estimation.complementary import ComplementaryConfig
from companion.estimation.madgwick import MadgwickConfig
from companion.param_kinds import (
    AttitudeMapTable,
    ComplementaryTable,
    DartEstimatorTable,
    DartFile,
    DartRuntimeTable,
    DartSimTable,
    MadgwickTable,
    RcMixerTable,
)
from companion_sitl.dart_sim import DartSim, load_dart_params, shipped_dart_params


def test_the_components_take_their_tables_as_they_are() -> None:
    assert MadgwickConfig is MadgwickTable and ComplementaryConfig is ComplementaryTable
    assert RcMixerConfig is RcMixerTable and AttitudeMapConfig is AttitudeMapTable
    # [runtime] is the mixer's config and the attitude map, [sim] an attitude map: their keys
    # are inherited, not declared again
    assert issubclass(DartRuntimeTable, RcMixerTable) and issubclass(DartRuntimeTable, AttitudeMapTable)
    assert issubclass(DartSimTable, AttitudeMapTable)
    for key in RcMixerTable.model_fields:
        assert key not in DartRuntimeTable.__annotations__, key
    for key in AttitudeMapTable.model_fields:
        assert key not in DartRuntimeTable.__annotations__ and key not in DartSimTable.__annotations__, key
    # the estimators' config adds the geometry (from [runtime] or [sim]) to [estimator]
    extra = DartEstimatorConfig.model_fields.keys() - DartEstimatorTable.model_fields.keys()
    assert extra == {"R_body_cam", "t_body_cam_m", "R_world_marker", "reference_yaw_rad", "gimbal_yaw_rad"}
    assert DartFile.model_fields["estimator"].annotation is DartEstimatorTable


def test_defaults_are_the_former_constants() -> None:
    m = MadgwickConfig()
    assert (m.mu, m.gamma, m.nominal_rate_hz, m.max_dt_s, m.accel_min_m_s2, m.accel_max_m_s2) == (
        0.1, 0.005, 200.0, 0.1, 1.0, 40.0,
    )  # fmt: skip
    c = ComplementaryConfig()
    assert (c.lam, c.wrap, c.max_dt_s) == (0.9, (True, True, True), 0.1)
    assert ComplementaryConfig.from_time_constant(0.3, 0.1).lam == 0.3 / 0.4
    e = DartEstimatorConfig()
    assert e.R_body_cam == camera_mount() and e.R_world_marker == wall_marker()
    assert (e.t_body_cam_m, e.reference_yaw_rad, e.gimbal_yaw_rad, e.yaw_offset_rad) == ((0.08, 0.0, 0.03), 0, 0, 0)
    assert (e.yaw_align_tau_s, e.history_s, e.max_attitude_age_s, e.max_rotation_error) == (None, 0.5, 0.2, 1e-3)
    g = PidGains(kp=1.0)
    assert (g.ki, g.kd, g.d_filter_tau_s, g.wrap_error, g.max_dt_s) == (0.0, 0.0, 0.1, False, 0.5)
    assert (g.out_min, g.out_max, g.i_min, g.i_max) == (-math.inf, math.inf, -math.inf, math.inf)
    d = DartControllerConfig()
    assert d.x == PidGains(
        kp=120.0, ki=20.0, kd=80.0, d_filter_tau_s=0.1, out_min=-200.0, out_max=200.0, i_min=-100.0, i_max=100.0
    )
    assert d.yaw == PidGains(kp=200.0, out_min=-150.0, out_max=150.0, wrap_error=True)
    assert (d.axis_channels, d.axis_signs, d.yaw_sign, d.rate_hz, d.max_estimate_age_s) == (
        ("roll", "throttle", "pitch"), (1.0, 1.0, 1.0), 1.0, 22.0, 0.3,
    )  # fmt: skip
    r = RcMixerConfig()
    assert (r.channels, r.signs, r.switch_channel, r.engage_above_us) == ((1, 2, 3, 4), (1.0,) * 4, 7, 1700.0)
    assert (r.min_us, r.max_us, r.neutral_us, r.valid_min_us, r.valid_max_us) == (1000, 2000, 1500, 800, 2200)
    assert r.max_contribution_us == (300.0, 300.0, 250.0, 300.0)
    a = AttitudeMapConfig()
    assert (a.max_tilt_rad, a.max_yaw_rate_rad_s) == (math.radians(35.0), math.radians(150.0))
    # the file's [control] defaults give the former loops' time limits
    cc = controller_config(DartControlGains())
    assert cc.max_estimate_age_s == 0.3 and {p.max_dt_s for p in (cc.x, cc.y, cc.z, cc.yaw)} == {0.5}


def test_runtime_mixes_as_the_mixer_config_with_its_values() -> None:
    rt = DartRuntimeConfig(stick_channels=(2, 1, 3, 4), stick_reversed=(False, True, False, False))
    same = RcMixerConfig(**{k: getattr(rt, k) for k in RcMixerTable.model_fields})
    pilot = [1600.0, 1450.0, 1500.0, 1520.0, 1500.0, 1500.0, 1900.0] + [1500.0] * 5

    class C:
        roll_us, pitch_us, thrust_us, yaw_rate_us = 40.0, -30.0, 20.0, 10.0

    assert RcMixer(rt).mix(pilot, C()) == RcMixer(same).mix(pilot, C())
    assert attitude_setpoint(pilot, C(), rt, rt) == attitude_setpoint(pilot, C(), same, AttitudeMapConfig())


def test_the_estimator_table_reaches_the_estimators(tmp_path: Path) -> None:
    f = tmp_path / "d.toml"
    f.write_text(
        "[estimator]\nhistory_s = 1.0\n[estimator.madgwick]\ngamma = 0.02\n"
        "[estimator.complementary]\nlam = 0.8\n[runtime]\nmarker_heading_deg = 90.0\n"
    )
    flight = load_dart_flight_params(f)
    cfg = estimator_config(flight.runtime, flight.estimator)
    assert cfg.history_s == 1.0 and cfg.madgwick.gamma == 0.02 and cfg.complementary.lam == 0.8
    assert cfg.R_world_marker == wall_marker(math.radians(90.0)) and cfg.reference_yaw_rad == math.radians(90.0)
    sim_params = load_dart_params(f)
    sim = DartSim("FCF-CF", sim_params.sim, sim_params.mission, estimator_table=sim_params.estimator)
    assert sim.estimator.config.madgwick.gamma == 0.02 and sim.estimator.config.complementary.lam == 0.8
    # the shipped file has no [estimator]: the defaults
    assert load_dart_params(shipped_dart_params()).estimator == DartEstimatorTable()


@pytest.mark.parametrize(
    "text, rule",
    [
        (
            "[estimator.madgwick]\ngamma = 2.0",
            "[estimator] madgwick.gamma = 2.0: Input should be less than or equal",
        ),
        ("[estimator.madgwick]\naccel_min_m_s2 = 50.0", "accel_min_m_s2 (50.0) must be < accel_max_m_s2 (40.0)"),
        (
            "[estimator.complementary]\nlam = '0.5'",
            "[estimator] complementary.lam = '0.5': Input should be a valid",
        ),
        ("[estimator]\nhistory_s = 0.0", "[estimator] history_s = 0.0: Input should be greater than 0"),
        ("[estimator]\nkp = 1.0", "[estimator] kp = 1.0: unknown key"),
        ("[runtime]\nengage_above_us = 2500.0", "engage_above_us = 2500.0: must lie inside min_us..max_us"),
        ("[runtime]\nneutral_us = 2100.0", "valid_min_us <= min_us < neutral_us < max_us <= valid_max_us"),
        ("[control]\nmax_estimate_age_s = 0.0", "[control] max_estimate_age_s = 0.0: Input should be greater than 0"),
    ],
)
def test_a_bad_value_names_file_key_value_and_rule(
    tmp_path: Path, text: str, rule: str, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text + "\n")
    for load in (load_dart_flight_params, load_dart_params):
        with pytest.raises(DartParamsError) as err:
            load(f)
        assert str(f) in str(err.value) and rule in str(err.value), str(err.value)
    assert main(["params", "check", "--kind", "dart", str(f)]) == 1
    out = capsys.readouterr().err
    assert str(f) in out, out


def test_params_show_lists_the_new_tables(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["params", "show", str(shipped_dart_params())]) == 0
    out = capsys.readouterr().out
    for line in (
        "[estimator.madgwick]",
        "estimator.madgwick.gamma = 0.005 [-] (>= 0.0, <= 1.0)",
        "estimator.complementary.lam = 0.9 [-] (>= 0.0, <= 1.0)",
        "estimator.history_s = 0.5 [s] (> 0.0)",
        "runtime.neutral_us = 1500.0 [us]",
        "control.max_estimate_age_s = 0.3 [s] (> 0.0)",
        "sim.max_tilt_deg = 35.0 [deg] (> 0.0, < 80.0)",
    ):
        assert line in out, line
