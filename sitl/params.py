"""The embedded simulator's parameters: ``[sim]``, ``[sim.vehicle]``, ``[sim.winch]`` of a vehicle
parameter file, declared as the application's sections are (unit, limits, description per key).

The application's config (:class:`companion.config.CompanionConfig`) takes the ``[sim]`` table as
it is, since the application never runs the simulator; :class:`SimulatedConfig` is that config with
the table validated, and the rules that tie it to the rest (the fence holds the simulated home, a
pad given in lat/lon lies near it, a simulated pad at the alternate needs the alternate). Read a
parameter file for the simulator with :func:`load_simulated_config`: an unknown key or a bad value
fails with a :class:`~companion.config.ConfigError` naming the file, the key, the value and the rule.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, model_validator

from companion.config import (
    PAD_OFFSET_MAX_M,
    CompanionConfig,
    GeoConfig,
    _f,
    _Section,
    read_params,
    validate_config,
)
from companion.geometry.earth import GeoPoint, geo_to_ned


class VehicleSimConfig(_Section):
    """Embedded multicopter model (sitl/): inner loops that behave like PX4's."""

    max_tilt_deg: float = _f(35.0, "deg", "tilt limit of the attitude loop", gt=5.0, le=70.0)
    max_horizontal_accel_m_s2: float = _f(5.0, "m/s^2", "horizontal acceleration limit", gt=0.1, le=20.0)
    max_up_accel_m_s2: float = _f(4.0, "m/s^2", "upward acceleration limit", gt=0.1, le=20.0)
    max_down_accel_m_s2: float = _f(3.0, "m/s^2", "downward acceleration limit", gt=0.1, le=9.8)
    attitude_time_constant_s: float = _f(0.12, "s", "first-order tilt response", gt=0.005, le=2.0)
    velocity_p_gain: float = _f(1.8, "1/s", "velocity loop P (MPC_XY_VEL_P_ACC-like)", gt=0.0, le=20.0)
    velocity_i_gain: float = _f(0.4, "1/s^2", "velocity loop I", ge=0.0, le=20.0)
    vertical_velocity_p_gain: float | None = _f(
        None, "1/s", "vertical velocity loop P (MPC_Z_VEL_P_ACC-like; default: velocity_p_gain)", gt=0.0, le=20.0
    )
    vertical_velocity_i_gain: float | None = _f(
        None, "1/s^2", "vertical velocity loop I (MPC_Z_VEL_I_ACC-like; default: velocity_i_gain)", ge=0.0, le=20.0
    )
    position_p_gain: float = _f(0.95, "1/s", "position loop P for hold/land (MPC_XY_P-like)", gt=0.0, le=10.0)
    drag_coefficient_1_s: float = _f(0.35, "1/s", "linear drag per unit air-relative speed", ge=0.0, le=5.0)
    takeoff_speed_m_s: float = _f(1.5, "m/s", "autopilot takeoff climb rate", gt=0.1, le=5.0)
    takeoff_altitude_acceptance_m: float = _f(
        0.05,
        "m",
        "the take-off is reported done (TAKEOFF -> HOLD, still climbing to its height) this far below it "
        "(PX4's NAV_MC_ALT_RAD)",
        gt=0.0,
        le=5.0,
    )
    land_speed_m_s: float = _f(0.7, "m/s", "autopilot LAND descent rate", gt=0.1, le=5.0)
    soft_ground: bool = _f(
        False,
        "-",
        "the ground stops the vehicle only while the net vertical force points down, where it is caught "
        "(PX4 SIH's fake ground, sih.cpp): a steady descent passes below the take-off level until the thrust "
        "drops; false: a hard ground at the take-off level",
    )
    offboard_loss_timeout_s: float = _f(1.0, "s", "COM_OF_LOSS_T: offboard setpoints lost -> hold", gt=0.1, le=60.0)
    offboard_max_horizontal_m_s: float = _f(
        30.0, "m/s", "the autopilot's own cut of an offboard velocity setpoint, horizontal (MPC_XY_VEL_MAX)", gt=0.0
    )
    offboard_max_up_m_s: float = _f(
        30.0, "m/s", "the autopilot's own cut of an offboard velocity setpoint, up (MPC_Z_VEL_MAX_UP)", gt=0.0
    )
    offboard_max_down_m_s: float = _f(
        30.0, "m/s", "the autopilot's own cut of an offboard velocity setpoint, down (MPC_Z_VEL_MAX_DN)", gt=0.0
    )
    physics_rate_hz: float = _f(200.0, "Hz", "integration rate", ge=50.0, le=2000.0)
    release_delay_s: float = _f(0.5, "s", "payload actuator travel time", ge=0.0, le=10.0)
    command_latency_s: float = _f(0.02, "s", "time for a command to be acknowledged", ge=0.0, le=5.0)
    battery_endurance_s: float = _f(1500.0, "s", "flight time from 100 % to 0 % battery", gt=10.0, le=36000.0)


class SimWinchConfig(_Section):
    """The simulated winch and parcel (sitl/winch.py; docs/winch.md)."""

    fitted: bool = _f(
        False,
        "-",
        "a winch is fitted (as ArduCopter with WINCH_TYPE = 1 and an output at SERVOn_FUNCTION = 88); false: "
        "DO_WINCH answers FAILED, as ArduCopter does without one",
    )
    rate_max_m_s: float = _f(0.5, "m/s", "the winch's largest line speed (ArduCopter WINCH_RATE_MAX)", gt=0.0, le=10.0)
    pos_p: float = _f(1.0, "1/s", "length control gain (ArduCopter WINCH_POS_P)", gt=0.0, le=10.0)
    stuck: bool = _f(
        False, "-", "the drum does not turn: the line never pays out (a failure; an encoder reports it as it is)"
    )
    reel_in_jams: bool = _f(
        False,
        "-",
        "the drum pays out but does not turn to reel in (a failure: a jammed level-wind, a line off its drum); an "
        "encoder winch reports the line as it is",
    )
    parcel_drag_1_s: float = _f(
        0.3, "1/s", "the parcel's linear air drag per unit air-relative speed (pulls it downwind)", ge=0.0, le=5.0
    )
    load_cell: bool = _f(
        False,
        "-",
        "the winch weighs its line: WINCH_STATUS carries the tension (the parcel's mass while it hangs, 0 when the "
        "line is slack); false: NaN, as ArduCopter's PWM winch sends it",
    )
    parcel_mass_kg: float = _f(0.5, "kg", "the parcel's mass (the load cell's reading while it hangs)", gt=0.0, le=20.0)
    hook_fails: bool = _f(
        False, "-", "the release moves its servo but the parcel stays on the hook (a failure: it comes up again)"
    )
    snag_height_m: float = _f(
        0.0,
        "m",
        "on its way down the parcel catches on an obstacle this high above the ground and hangs there, the line "
        "slack (a failure; 0: none)",
        ge=0.0,
        le=30.0,
    )
    draw_parcel: bool = _f(
        False,
        "-",
        "the simulated camera sees the parcel once its line is out: a box with a level top (false: not drawn, the "
        "frames as before)",
    )
    parcel_tag: bool = _f(
        True, "-", "with draw_parcel: the parcel's top carries the tag [winch.camera] describes (false: a plain box)"
    )
    parcel_size_m: float = _f(0.3, "m", "with draw_parcel: the side of the parcel's square top", gt=0.0, le=3.0)
    parcel_height_m: float = _f(0.25, "m", "with draw_parcel: the parcel's height", ge=0.0, le=3.0)


class SimOccluderConfig(_Section):
    """Something on or around the pad in the simulated camera's frames (companion_sitl.camera_occluders,
    docs/drop-zone.md): drawn from the scenario's seed; off by default."""

    kind: Literal["none", "box", "person", "shadow"] = _f(
        "none",
        "-",
        "a box lying on the pad, a person walking into its margin, or a shadow band across it (not an object)",
    )
    window_s: float = _f(
        8.0,
        "s",
        "the person enters the margin at a moment drawn in the first 60 % of this window, timed from the first "
        "frame with the pad in view (below from_height_m)",
        gt=0.0,
        le=600.0,
    )
    from_height_m: float = _f(
        0.0,
        "m",
        "the occluder's clock starts at the first frame with the pad in view and the vehicle truly below this "
        "height (a person walking in during the final descent; 0: at any height)",
        ge=0.0,
        le=500.0,
    )


class SimCameraConditionsConfig(_Section):
    """What a real board camera adds to the simulated frames (companion_sitl.camera_conditions,
    docs/vision.md#a-real-cameras-images); every key off by default."""

    exposure_s: float = _f(
        0.0,
        "s",
        "exposure time: the frame is smeared by the image's motion during it (0: no motion blur)",
        ge=0.0,
        le=0.1,
    )
    rolling_shutter_s: float = _f(
        0.0,
        "s",
        "readout from the top row to the bottom one (a Pi camera v2 at 640x480: about 0.02; 0: global shutter)",
        ge=0.0,
        le=0.1,
    )
    exposure_steps_s: float = _f(
        0.0, "s", "auto-exposure steps under passing clouds: their mean interval (0: none)", ge=0.0, le=600.0
    )
    exposure_step_gain: float = _f(0.45, "-", "brightness during a step, before auto-exposure recovers", gt=0.0, le=4.0)
    exposure_recover_s: float = _f(0.6, "s", "auto-exposure's time to recover from a step", gt=0.0, le=10.0)
    shadow: float = _f(
        0.0, "-", "darkening inside a shadow band drifting across the frame (0.6: 60 % darker; 0: none)", ge=0.0, lt=1.0
    )
    glare: float = _f(
        0.0, "grey levels", "brightness a glare spot adds at its centre (sun on the pad; 0: none)", ge=0.0, le=255.0
    )
    low_light_noise: float = _f(0.0, "grey levels", "extra sensor noise of a dim scene (std; 0: none)", ge=0.0, le=50.0)
    jpeg_quality: int = _f(0, "-", "JPEG quality of an MJPG camera's frames, 1-100 (0: raw frames)", ge=0, le=100)
    drop_fraction: float = _f(0.0, "-", "share of the frames the driver drops", ge=0.0, le=0.5)
    late_s: float = _f(0.0, "s", "extra latency of a frame, drawn uniformly up to this (0: none)", ge=0.0, le=0.5)
    unknown_latency_s: float = _f(
        0.0,
        "s",
        "the frames reach the companion this much later than landing.camera_latency_s says, a latency the "
        "configuration does not know about (docs/clock.md; 0: none)",
        ge=0.0,
        le=0.5,
    )
    driver_stamp: bool = _f(
        False,
        "-",
        "the frames carry the driver's honest capture stamp and their arrival time (landing.camera_time = "
        "driver / measured use them; docs/clock.md)",
    )
    occluder: SimOccluderConfig = Field(default_factory=SimOccluderConfig)


class SimPadMotionConfig(_Section):
    """The simulated pad on a moving vehicle (a van, a boat; companion_sitl.pad_motion, docs/moving-pad.md):
    it stands at its place until ``start_s``, speeds up along ``course_deg`` at ``accel_m_s2`` to
    ``speed_m_s``, then drives on at that speed turning at ``turn_rate_deg_s``; the camera's target, the
    UWB anchors and the truth scoring follow it. Off by default (speed 0)."""

    speed_m_s: float = _f(
        0.0, "m/s", "the pad's ground speed once up to speed (0: the pad stands still)", ge=0.0, le=10.0
    )
    course_deg: float = _f(
        0.0, "deg", "the direction the pad starts moving in (0 = north, 90 = east)", ge=0.0, lt=360.0
    )
    turn_rate_deg_s: float = _f(
        0.0,
        "deg/s",
        "the pad's course (and heading) turns at this rate once up to speed (> 0: to the right; 0: straight)",
        ge=-30.0,
        le=30.0,
    )
    accel_m_s2: float = _f(
        0.5, "m/s^2", "the pad's acceleration from standing to speed_m_s (straight)", gt=0.0, le=10.0
    )
    start_s: float = _f(
        0.0, "s", "simulated time the pad starts moving (before it stands at its place)", ge=0.0, le=36000.0
    )
    deck_size_m: float = _f(
        2.0,
        "m",
        "side of the moving vehicle's deck, a square centred on the pad and turned with it: a vehicle resting on "
        "it rides along (as on a van's roof); off it, on the ground",
        gt=0.0,
        le=50.0,
    )


class SimConfig(_Section):
    """A simulated scenario: seed, home, wind, sensors."""

    seed: int = _f(1, "-", "random seed (every noise source derives from it)", ge=0)
    profile: Literal["ideal", "px4-sih", "arducopter-sitl"] = _f(
        "ideal",
        "-",
        "autopilot behaviour measured on the real firmware SITL (estimate errors, velocity response, land "
        "detector, start-up delay, wind model; sitl/profiles.py); it overrides the fields it fixes",
    )
    profile_weather: bool = _f(
        False,
        "-",
        "with a firmware profile: keep this file's gusts and GPS noise and wander instead of the profile's "
        "calm SITL defaults (the weather `campaign landing --autopilot ardupilot --weather` drives on the real "
        "SITL; docs/weather.md)",
    )
    home: GeoConfig = Field(default_factory=lambda: GeoConfig(lat_deg=-19.869, lon_deg=-43.9638, alt_amsl_m=850.0))
    wind_speed_m_s: float = _f(0.0, "m/s", "mean wind speed", ge=0.0, le=25.0)
    wind_from_deg: float = _f(270.0, "deg", "direction the wind blows from (0 = north)", ge=0.0, lt=360.0)
    gust_std_m_s: float = _f(-1.0, "m/s", "gust intensity (std); -1 = 20 % of wind speed", ge=-1.0, le=10.0)
    gust_time_constant_s: float = _f(3.0, "s", "gust correlation time", gt=0.0, le=60.0)
    gps_bias_m: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "m", "constant GPS error (N, E, D)")
    gps_noise_m: float = _f(0.05, "m", "white GPS noise (std, horizontal)", ge=0.0, le=10.0)
    gps_walk_m: float = _f(0.15, "m", "slow GPS error wander (std, horizontal, Gauss-Markov)", ge=0.0, le=10.0)
    gps_walk_time_constant_s: float = _f(20.0, "s", "correlation time of the GPS wander", gt=0.0, le=3600.0)
    height_estimate_scale_error: float = _f(
        0.0,
        "-",
        "the autopilot's height estimate reads (1 + this) x the true height above home (PX4 v1.16 SIH in flight: "
        "+0.10 to +0.14, sitl/profiles.py)",
        ge=-0.5,
        le=0.5,
    )
    height_estimate_drift_m_s: float = _f(
        0.0,
        "m/s",
        "the autopilot's height estimate drifts up from the true height at this rate while armed (PX4 v1.16 "
        "SIH, GPS only: 0.3-1.7 m within one 20 s flight; docs/rangefinder.md)",
        ge=-1.0,
        le=1.0,
    )
    gps_rate_hz: float = _f(8.0, "Hz", "GPS fix rate", gt=0.5, le=50.0)
    position_rate_hz: float = _f(30.0, "Hz", "LOCAL/GLOBAL_POSITION stream rate", gt=1.0, le=200.0)
    attitude_rate_hz: float = _f(50.0, "Hz", "ATTITUDE stream rate", gt=1.0, le=500.0)
    imu_rate_hz: float = _f(50.0, "Hz", "IMU stream rate", gt=1.0, le=1000.0)
    status_rate_hz: float = _f(5.0, "Hz", "status/heartbeat rate", gt=0.5, le=50.0)
    gyro_noise_rad_s: float = _f(0.003, "rad/s", "gyro white noise", ge=0.0, le=1.0)
    accel_noise_m_s2: float = _f(0.05, "m/s^2", "accelerometer white noise", ge=0.0, le=10.0)
    baro_noise_m: float = _f(0.1, "m", "barometer white noise", ge=0.0, le=10.0)
    ready_delay_s: float = _f(2.0, "s", "time after boot until the vehicle is healthy (GPS, EKF)", ge=0.0, le=120.0)
    pad_offset_m: tuple[float, float] = _f((0.0, 0.0), "m", "true pad displacement from its configured position (N, E)")
    pad_heading_offset_deg: float = _f(
        0.0,
        "deg",
        "the true pad's heading minus its configured mission.pad.heading_deg (a dock placed slightly "
        "rotated; only with a pad heading configured)",
        ge=-180.0,
        le=180.0,
    )
    gnss_lost_below_m: float = _f(
        0.0,
        "m",
        "> 0: the GPS goes off (sitl/gnss_loss.py: ArduCopter and PX4 SIH profiles) the first time the true "
        "vehicle comes down through this height above the ground within gnss_lost_within_m of the true pad; 0 = never",
        ge=0.0,
        le=1000.0,
    )
    gnss_lost_within_m: float = _f(
        6.0, "m", "how near the true pad the GPS goes off (gnss_lost_below_m)", gt=0.0, le=10000.0
    )
    camera_fails_below_m: float = _f(
        0.0,
        "m",
        "the simulated landing camera gives no frame below this true height above the pad (a failure; "
        "0 = never; higher than the flight = failed all flight)",
        ge=0.0,
        le=10000.0,
    )
    camera_range_m: float = _f(
        0.0,
        "m",
        "the simulated landing camera gives no frame above this true height above the pad (a short detection "
        "range; 0 = unlimited)",
        ge=0.0,
        le=10000.0,
    )
    uwb_fails_below_m: float = _f(
        0.0,
        "m",
        "the simulated UWB gives no ranging below this true height above the pad (0 = never; higher than "
        "the flight = failed all flight)",
        ge=0.0,
        le=10000.0,
    )
    pad_at_alternate: bool = _f(
        False,
        "-",
        "the simulated pad (the camera's target, the UWB anchors) lies at mission.alternate_pad (plus "
        "pad_offset_m), and none at mission.pad: a delivery whose first pad is missing",
    )
    vehicle: VehicleSimConfig = Field(default_factory=VehicleSimConfig)
    winch: SimWinchConfig = Field(default_factory=SimWinchConfig)
    camera: SimCameraConditionsConfig = Field(default_factory=SimCameraConditionsConfig)
    pad_motion: SimPadMotionConfig = Field(default_factory=SimPadMotionConfig)

    @model_validator(mode="after")
    def _finite(self) -> SimConfig:
        for name in ("gps_bias_m", "pad_offset_m"):
            for v in getattr(self, name):
                if not math.isfinite(v) or abs(v) > 1000.0:
                    raise ValueError(f"{name} component {v} must be finite and within +-1000 m")
        if self.profile_weather and self.profile != "arducopter-sitl":
            raise ValueError(
                f"profile_weather = true with profile {self.profile!r}: only the arducopter-sitl profile has a "
                "weather to keep (PX4 SIH v1.16 has no wind; ideal flies this file's weather anyway)"
            )
        return self

    @property
    def gust_std_effective_m_s(self) -> float:
        return 0.2 * self.wind_speed_m_s if self.gust_std_m_s < 0 else self.gust_std_m_s


class SimulatedConfig(CompanionConfig):
    """:class:`~companion.config.CompanionConfig` with its ``[sim]`` table validated: the config
    the simulator, the lab and the command line's simulated flights read."""

    sim: SimConfig = Field(default_factory=SimConfig)  # type: ignore[assignment]  # the table, validated

    def _fenced_points(self) -> list[tuple[float, float, str]]:
        """The simulated home (with ``autopilot = "sim"``), then the application's points."""
        points = super()._fenced_points()
        if self.autopilot == "sim":
            h = self.sim.home
            points.insert(0, (h.lat_deg, h.lon_deg, "sim.home"))
        return points

    @model_validator(mode="after")
    def _geodetic_pads_near_sim_home(self) -> SimulatedConfig:
        """A pad given in lat/lon lies within PAD_OFFSET_MAX_M (north and east) of the simulated
        home, as a pad given in north/east must (a real home is only known in flight: the
        planner checks it there)."""
        if self.autopilot != "sim":
            return self
        h = self.sim.home
        home = GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m)
        for key, pad in (("mission.pad", self.mission.pad), ("mission.alternate_pad", self.mission.alternate_pad)):
            if pad is None or pad.lat_deg is None or pad.lon_deg is None:
                continue
            north_m, east_m, _ = geo_to_ned(home, GeoPoint(pad.lat_deg, pad.lon_deg, h.alt_amsl_m))
            if max(abs(north_m), abs(east_m)) > PAD_OFFSET_MAX_M:
                raise ValueError(
                    f"{key} ({pad.lat_deg}, {pad.lon_deg}) lies {north_m:.0f} m north, {east_m:.0f} m east of "
                    f"sim.home: each must be within +-{PAD_OFFSET_MAX_M:g} m"
                )
        return self

    @model_validator(mode="after")
    def _simulated_pad_at_alternate(self) -> SimulatedConfig:
        """A simulated pad at the alternate needs the alternate pad."""
        if self.sim.pad_at_alternate and self.mission.alternate_pad is None:
            raise ValueError("sim.pad_at_alternate = true needs mission.alternate_pad (where the simulated pad lies)")
        return self


def simulated_config_from_dict(data: dict[str, Any], source: str = "<dict>") -> SimulatedConfig:
    """:func:`companion.config.config_from_dict` for the simulator: ``[sim]`` validated too."""
    return validate_config(SimulatedConfig, data, source)


def load_simulated_config(*paths: str | Path, overrides: dict[str, Any] | None = None) -> SimulatedConfig:
    """:func:`companion.config.load_config` for the simulator: ``[sim]`` validated too."""
    return simulated_config_from_dict(*read_params(*paths, overrides=overrides))


__all__ = [
    "SimConfig",
    "SimPadMotionConfig",
    "SimWinchConfig",
    "SimulatedConfig",
    "VehicleSimConfig",
    "load_simulated_config",
    "simulated_config_from_dict",
]
