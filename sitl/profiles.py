"""Autopilot profiles: the embedded simulator (and the MAVLink sim vehicle built on it) behaving
like a given firmware, chosen by name with ``[sim] profile``.

The figures come from the real SITL, measured with the firmware probe (``companion campaign probe
--autopilot px4|ardupilot``: hover, a 2 m/s step, a descent onto the ground, truth beside what the
autopilot reports) and from traced landings (``companion campaign parity``); see docs/simulation.md.

PX4 SIH's velocity estimate is not consistent with its position estimate, so the profile models
the two errors independently: the velocity loop (and the reported velocity) sees truth + a
Gauss-Markov error; the reported position (and the position loops) truth + a separate
Gauss-Markov wander. Its estimator also settles at start-up into one of a few states (a constant
attitude offset, a horizontal velocity bias that the vehicle flies on, traced over a steady descent
from 3 m and replayed by the time since the descent passed 3 m); the traced states are
``data/px4_sih_traced.toml`` and one is drawn per flight. PX4 steers its attitude
estimate, so the vehicle's true attitude is the setpoint minus that offset.

ArduCopter's GUIDED velocity is flown as AC_PosControl flies it: the setpoint shaped with the
firmware's jerk and acceleration limits into a position target held on the estimate; its gains
are the firmware's own (PSC_POSXY_P, PSC_VELXY_P / _I, PSC_JERK_XY, WPNAV_ACCEL).

``ideal`` is the embedded simulator without any firmware's errors.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

from companion_sitl.params import SimConfig

PROFILE_NAMES = ("ideal", "px4-sih", "arducopter-sitl")


@dataclass(frozen=True)
class EstimatorState:
    """One state a firmware's estimator settles into at start-up and keeps through the flight.

    Measured on PX4 v1.16 SIH (docs/notes.md, *PX4 SIH's estimator states*): every start
    settles into one of a few, seen in the attitude it reports (a constant offset from the truth)
    and in its horizontal velocity estimate (a bias that follows the same curve over height in
    every flight of the state, where PX4 flies on it)."""

    name: str
    probability: float
    # reported - true attitude, roll / pitch / yaw, degrees
    attitude_bias_deg: tuple[float, float, float]
    # reported - true horizontal velocity (N, E), m/s, at the heights in VELOCITY_BIAS_HEIGHTS_M
    # (the midpoints of the bands it was measured on), linear between them and constant outside;
    # in a descent from above VELOCITY_BIAS_DESCENT_START_M, read by the time since passing it
    velocity_bias_m_s: tuple[tuple[float, float], ...]
    # the position estimate follows that bias for a while before GPS pulls it back: its error
    # e obeys de/dt = bias - e / tau (fitted to the traced flights)
    position_follows_bias_tau_s: float = 0.5


#: PX4 v1.16 SIH's traced estimator errors (where and how they were traced: the file's header)
_PX4_SIH_TRACED = tomllib.loads(
    resources.files("companion_sitl").joinpath("data/px4_sih_traced.toml").read_text(encoding="utf-8")
)

# the midpoints of the height bands the velocity bias was measured on (the final descent; above
# the top band its value holds)
VELOCITY_BIAS_HEIGHTS_M: tuple[float, ...] = tuple(_PX4_SIH_TRACED["velocity_bias_heights_m"])
# the traced descent (from this height at this speed): below that height on the way down, the bias
# is read at the height the traced descent had reached after the same time (a wander in time)
VELOCITY_BIAS_DESCENT_START_M: float = float(_PX4_SIH_TRACED["descent_start_height_m"])
VELOCITY_BIAS_DESCENT_SPEED_M_S: float = float(_PX4_SIH_TRACED["descent_speed_m_s"])
# past the traced descent's lowest band the bias drifts on at a rate drawn per flight and axis
VELOCITY_BIAS_DRIFT_RATE_M_S2: float = float(_PX4_SIH_TRACED["velocity_bias_drift_rate_m_s2"])
VELOCITY_BIAS_DRIFT_MAX_M_S: float = float(_PX4_SIH_TRACED["velocity_bias_drift_max_m_s"])


@dataclass(frozen=True)
class AutopilotProfile:
    name: str
    description: str
    # the autopilot's velocity-estimate error: Gauss-Markov per axis (std, correlation time);
    # 0 = the velocity loop runs on truth (ideal)
    velocity_error_m_s: float = 0.0
    velocity_error_down_m_s: float = 0.0
    velocity_error_tau_s: float = 1.0
    # whether that error drives the vehicle: PX4's offboard velocity loop closes on its velocity
    # estimate, so the vehicle drifts on the error; ArduCopter's GUIDED velocity control advances a
    # position target by the requested velocity and closes on its position estimate
    # (AC_PosControl::input_vel_accel_xy), so the error does not accumulate (the reported velocity
    # keeps it either way)
    velocity_loop_on_estimate: bool = True
    # the estimator's states, one drawn per flight by probability (none: no per-flight bias)
    estimator_states: tuple[EstimatorState, ...] = ()
    land_detect_s: float = 0.6
    # > 0: the autopilot's estimate takes the GPS error (the profile's wander and its 5 Hz fix
    # noise) with this time constant instead of at once, and its velocity estimate carries the
    # rate at which it does (ArduCopter's EKF3); 0: the estimate is truth + the error
    gps_error_estimate_tau_s: float = 0.0
    # > 0: the estimate takes it through a second-order response instead, natural frequency
    # 1 / gps_error_estimate_tau_s and this damping ratio (an estimator that carries a velocity
    # state overshoots a step)
    gps_error_estimate_damping: float = 0.0
    # the share of the rate at which the estimate takes the error that the velocity estimate the
    # velocity loop closes on carries (1: an estimate whose velocity is its position's rate)
    gps_error_velocity_share: float = 1.0
    # > 0: an offboard velocity setpoint is flown as ArduCopter's GUIDED flies it
    # (AC_PosControl::input_vel_accel_xy, then update_xy_controller): shaped into a desired
    # velocity and acceleration (the velocity error closed with jerk / accel, square root above
    # the linear range, acceleration and jerk limited), the desired velocity integrated into a
    # position target, and the velocity loop asked for the desired velocity + position P x
    # (target - estimate) with the desired acceleration fed forward. A wind change or a GPS error
    # then moves the vehicle only until the target pulls it back. 0: the velocity loop takes the
    # setpoint as it comes (PX4's offboard velocity)
    guided_jerk_max_m_s3: float = 0.0  # PSC_JERK_XY
    guided_accel_max_m_s2: float = 2.5  # WPNAV_ACCEL
    guided_position_p_1_s: float = 1.0  # PSC_POSXY_P
    has_wind: bool = True
    # wind x sqrt(height / H) below H (ArduPilot SITL's default SIM_WIND_T = 0, SIM_WIND_T_ALT =
    # 60 m: no wind on the ground); 0 = the same wind at every height
    wind_ramp_height_m: float = 0.0
    # SimConfig fields the firmware fixes (position wander, start-up delay, ...)
    sim: dict[str, Any] = field(default_factory=dict)
    # VehicleSimConfig fields (velocity loop, limits)
    vehicle: dict[str, Any] = field(default_factory=dict)

    @property
    def ideal(self) -> bool:
        return self.name == "ideal"


# one state per traced flight, equally likely
PX4_SIH_STATES = tuple(
    EstimatorState(
        f"T{k + 1}",
        1.0 / len(_PX4_SIH_TRACED["flight"]),
        attitude_bias_deg=(f["attitude_bias_deg"][0], f["attitude_bias_deg"][1], f["attitude_bias_deg"][2]),
        velocity_bias_m_s=tuple((n, e) for n, e in f["velocity_bias_m_s"]),
    )
    for k, f in enumerate(_PX4_SIH_TRACED["flight"])
)

PROFILES: dict[str, AutopilotProfile] = {
    "ideal": AutopilotProfile("ideal", "the embedded model as designed: velocity loop on truth, 0.6 s land detector"),
    "px4-sih": AutopilotProfile(
        "px4-sih",
        "PX4 v1.16 SIH: one of ten traced flights' estimator errors per landing (attitude reported up to "
        "2 deg off in tilt and 13 in heading and steered on, velocity estimate biased up to 0.6 m/s over the "
        "time since the descent passed 3 m, drifting on past the traced 5.7 s, and flown on), "
        "position wander 0.12 m (2.5 s), take-off done 0.8 m short (NAV_MC_ALT_RAD), a soft ground (a steady "
        "descent sinks below the take-off level), 2.3 s land detector, no wind",
        # around the estimator state's bias: SD 0.01-0.14 m/s per band and flight in the traced landings
        velocity_error_m_s=0.07,
        velocity_error_down_m_s=0.13,
        velocity_error_tau_s=2.5,  # autocorrelation 1/e at 2.2-2.7 s
        estimator_states=PX4_SIH_STATES,
        land_detect_s=2.26,
        has_wind=False,  # SIH v1.16 has no wind parameters
        sim={
            "gps_walk_m": 0.12,  # position error std 0.09 / 0.14 m (N / E), 0.19 m down (1.5x)
            "gps_walk_time_constant_s": 2.5,
            "ready_delay_s": 5.0,
            # in flight the height estimate reads 10-14 % high (measured on sitl_short flights)
            "height_estimate_scale_error": 0.12,
        },
        vehicle={
            # fitted to PX4's velocity estimate against the companion's setpoints in traced landings
            # (small commands are answered slower than the probe's 2 m/s step suggests)
            "velocity_p_gain": 1.3,
            "velocity_i_gain": 0.3,
            "drag_coefficient_1_s": 0.75,
            # PX4's vertical velocity loop is its own and stiffer (MPC_Z_VEL_P_ACC 4.0, _I_ACC 2.0,
            # the v1.16 defaults)
            "vertical_velocity_p_gain": 4.0,
            "vertical_velocity_i_gain": 2.0,
            "max_horizontal_accel_m_s2": 3.0,
            "land_speed_m_s": 0.7,  # MPC_LAND_SPEED (measured descent 0.64 m/s)
            # SIH's ground catches the vehicle only when the net force points down (sih.cpp)
            "soft_ground": True,
            "takeoff_speed_m_s": 1.5,
            # PX4 leaves TAKEOFF for HOLD within NAV_MC_ALT_RAD (0.8 m, the v1.16 default) of the
            # take-off height and climbs on to it in HOLD; the companion may read well short of its
            # 90 % at that moment
            "takeoff_altitude_acceptance_m": 0.8,
            "offboard_loss_timeout_s": 1.0,  # COM_OF_LOSS_T
            "offboard_max_horizontal_m_s": 12.0,  # MPC_XY_VEL_MAX
            "offboard_max_up_m_s": 3.0,  # MPC_Z_VEL_MAX_UP
            "offboard_max_down_m_s": 1.5,  # MPC_Z_VEL_MAX_DN (measured: 2.16 m/s asked, 1.25-1.34 flown)
        },
    ),
    "arducopter-sitl": AutopilotProfile(
        "arducopter-sitl",
        "ArduCopter 4.7 SITL: near-perfect estimate (2 cm, 2 cm/s), GUIDED velocity shaped into a "
        "position target held on the estimate (63 % of a 2 m/s step in 0.9 s; a GPS error or a gust moves "
        "the vehicle until the target pulls it back), 1.4 s land detector, armable after 41 s, SIM_WIND_* "
        "wind without turbulence and fading to nothing on the ground",
        velocity_error_m_s=0.017,
        velocity_error_down_m_s=0.006,
        velocity_error_tau_s=2.3,
        # GUIDED closes on the position estimate: hovering on a zero setpoint the real vehicle stays
        # within a few cm (the probe), where a loop flying on this error would wander
        velocity_loop_on_estimate=False,
        land_detect_s=1.38,
        # the estimate's response and the drag fitted (with GUIDED's own gains below) to the truth's
        # response to a 0.1 m SIM_GPS1_GLTCH_X sine and to a 1 m/s wind sine at 0.05-0.5 Hz in
        # GUIDED (gps_step_probe --sine-hz; firmware-ardupilot.md)
        gps_error_estimate_tau_s=1.0,
        gps_error_estimate_damping=0.54,
        gps_error_velocity_share=0.26,
        guided_jerk_max_m_s3=5.0,  # PSC_JERK_XY
        guided_accel_max_m_s2=2.5,  # WPNAV_ACCEL 250 cm/s^2
        guided_position_p_1_s=1.0,  # PSC_POSXY_P
        wind_ramp_height_m=60.0,  # SIM_WIND_T = 0 (WIND_TYPE_SQRT), SIM_WIND_T_ALT = 60 m (SITL.cpp defaults)
        sim={
            "gps_walk_m": 0.02,
            "gps_walk_time_constant_s": 3.0,
            "gps_noise_m": 0.0,
            "gust_std_m_s": 0.0,  # SIM_WIND_TURB = 0 in the real campaign
            "ready_delay_s": 41.0,
        },
        vehicle={
            "velocity_p_gain": 2.0,  # PSC_VELXY_P (AC_PosControl.h POSCONTROL_VEL_XY_P)
            "velocity_i_gain": 1.0,  # PSC_VELXY_I (POSCONTROL_VEL_XY_I)
            "drag_coefficient_1_s": 0.30,  # fitted with the wind sine (above)
            # the tilt limits the acceleration (GUIDED's shaping keeps it to WPNAV_ACCEL): the 2 m/s
            # step's 63 % in 0.88 s, as measured
            "max_tilt_deg": 30.0,  # ANGLE_MAX 3000 cdeg
            "max_horizontal_accel_m_s2": 10.0,
            "land_speed_m_s": 0.5,  # LAND_SPEED 50 cm/s
            "offboard_loss_timeout_s": 3.0,  # GUID_TIMEOUT
        },
    ),
}


def get_profile(name: str) -> AutopilotProfile:
    try:
        return PROFILES[name]
    except KeyError:
        raise ValueError(f"autopilot profile {name!r}: expected one of {', '.join(PROFILE_NAMES)}") from None


# the [sim] fields of the weather and GPS error that `sim.profile_weather` keeps from the file
WEATHER_KEYS = ("gust_std_m_s", "gust_time_constant_s", "gps_noise_m", "gps_walk_m", "gps_walk_time_constant_s")


def apply_profile(sim: SimConfig) -> SimConfig:
    """``sim`` with the fields its profile fixes; ``ideal`` returns ``sim`` itself."""
    p = get_profile(sim.profile)
    if p.ideal:
        return sim
    update: dict[str, Any] = dict(p.sim)
    if sim.profile_weather:  # the drawn weather the real SITL is driven with (lab/real_weather.py)
        for key in WEATHER_KEYS:
            update.pop(key, None)
    if not p.has_wind:
        update.update(wind_speed_m_s=0.0, gust_std_m_s=0.0)
    update["vehicle"] = sim.vehicle.model_copy(update=p.vehicle)
    return sim.model_copy(update=update)
