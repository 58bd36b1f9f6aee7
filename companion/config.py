"""Typed, validated configuration loaded from TOML parameter sets in ``params/``.

Every parameter is declared once, here, with its unit, limits and description (``Field``).
An unknown key, a wrong type or an out-of-range value fails at load time with a
:class:`ConfigError` naming the file, the dotted key, the offending value and the rule. The
``[sim]`` tables are the embedded simulator's: taken as they are here, declared and validated in
``companion_sitl.params`` (``SimulatedConfig``, ``load_simulated_config``).
"""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from companion.geometry.polygon import point_in_polygon, polygon_problem


class ConfigError(ValueError):
    """A parameter file is unreadable or a value in it breaks a rule."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = problems
        super().__init__(f"{source}: " + "; ".join(problems))


def _f(default: Any, unit: str, description: str, **limits: Any) -> Any:
    return Field(default, description=description, json_schema_extra={"unit": unit}, **limits)


#: the pad's north and east offsets from home are each within this (m): a delivery radius a
#: multicopter flies on one battery, and what the path, the recorder and the simulator are sized for
PAD_OFFSET_MAX_M = 3000.0
#: an altitude above mean sea level is within these (m): the Dead Sea shore to above the highest peaks
ALT_AMSL_MIN_M, ALT_AMSL_MAX_M = -500.0, 9000.0


class _Section(BaseModel):
    # allow_inf_nan=False: every float of every section (tuples of floats included) is finite at
    # load; a NaN or infinity is refused as "not finite", never compared with a limit
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True, allow_inf_nan=False)


class GeoConfig(_Section):
    # within 89 deg of the equator: the pad's box around home and the simulated GPS errors (a few
    # km) stay off the poles, where the flat-earth model (delivery 4.1) would put a point past 90
    lat_deg: float = _f(..., "deg", "latitude (WGS-84), within 89 deg of the equator", ge=-89.0, le=89.0)
    lon_deg: float = _f(..., "deg", "longitude (WGS-84)", ge=-180.0, le=180.0)
    alt_amsl_m: float = _f(0.0, "m", "altitude above mean sea level", ge=ALT_AMSL_MIN_M, le=ALT_AMSL_MAX_M)


class PadConfig(_Section):
    """Where the delivery pad is: geodetic (as a customer's surveyed pad is) or local offsets."""

    lat_deg: float | None = _f(None, "deg", "pad latitude (give lat/lon, or north/east)", ge=-90, le=90)
    lon_deg: float | None = _f(None, "deg", "pad longitude", ge=-180, le=180)
    alt_amsl_m: float | None = _f(
        None, "m", "pad ground altitude AMSL (default: home altitude)", ge=ALT_AMSL_MIN_M, le=ALT_AMSL_MAX_M
    )
    north_m: float | None = _f(
        None,
        "m",
        "pad north of home (local alternative to lat/lon); a pad given as lat/lon must lie as near",
        ge=-PAD_OFFSET_MAX_M,
        le=PAD_OFFSET_MAX_M,
    )
    east_m: float | None = _f(
        None,
        "m",
        "pad east of home (local alternative to lat/lon); a pad given as lat/lon must lie as near",
        ge=-PAD_OFFSET_MAX_M,
        le=PAD_OFFSET_MAX_M,
    )
    up_m: float = _f(0.0, "m", "pad height above home ground (with north/east)", ge=-100, le=100)
    size_m: float = _f(1.0, "m", "side of the square landing pad", gt=0.1, le=10.0)
    heading_deg: float | None = _f(
        None,
        "deg",
        "the pad's heading (a dock, a charger, a locker): the NED direction, clockwise from north, in "
        "which the printed pad's 'up' edge (the ArUco marker's +y axis) points; the vehicle turns its "
        "nose to it in the final descent and touches down aligned. None = no alignment (the vehicle "
        "keeps the path's heading, as before). The heading the camera measures wins once measured "
        "(docs/pad-heading.md)",
        ge=-180.0,
        le=360.0,
    )
    heading_tolerance_deg: float = _f(
        20.0,
        "deg",
        "sanity bound on the measured pad heading: a camera measurement further than this from "
        "heading_deg is rejected (a wrong marker, a flipped pose) and the configured heading stays",
        gt=0.0,
        le=180.0,
    )

    @model_validator(mode="after")
    def _one_form(self) -> PadConfig:
        geo = self.lat_deg is not None or self.lon_deg is not None
        local = self.north_m is not None or self.east_m is not None
        if geo == local:
            raise ValueError("give the pad either as lat_deg+lon_deg or as north_m+east_m (one form)")
        if geo and (self.lat_deg is None or self.lon_deg is None):
            raise ValueError("pad lat_deg and lon_deg go together")
        if local and (self.north_m is None or self.east_m is None):
            raise ValueError("pad north_m and east_m go together")
        return self


def read_moved_keys(data: Any, moved: dict[str, str], table: str, sub: str) -> Any:
    """The keys of ``table`` (as read, before validation) with those that moved into its table
    ``sub`` (``moved``: old key -> key in ``sub``) read there: older files, and the parameters
    an older run folder keeps, still load (docs/parameters.md, Keys that moved). A file that
    sets one key in both places is refused."""
    if not isinstance(data, dict) or not any(k in data for k in moved):
        return data
    into = data.get(sub, {})
    if not isinstance(into, dict):
        return data  # the table's own error names it
    data, into = dict(data), dict(into)
    for old, new in moved.items():
        if old not in data:
            continue
        if new in into:
            raise ValueError(
                f"{table}.{old} and {table}.{sub}.{new} both set: {old} is the old name of {table}.{sub}.{new}; "
                f"keep {table}.{sub}'s"
            )
        into[new] = data.pop(old)
    data[sub] = into
    return data


class DescentConfig(_Section):
    """The final descent's controller (companion.guidance.descent.PrecisionDescent):
    ``[mission.descent]``. The horizontal error from the target is closed proportionally, plus an
    integral term and an acceleration fed forward when set; the descent slows and holds while off
    the target (docs/flying.md)."""

    xy_gain_1_s: float = _f(3.0, "1/s", "horizontal speed per metre off the target", gt=0.0, le=10.0)
    xy_tolerance_m: float = _f(
        0.1,
        "m",
        "while the pad is in sight (camera or UWB): slows when farther than this off the target, and holds at twice it",
        gt=0.01,
        le=5.0,
    )
    max_xy_speed_m_s: float = _f(1.0, "m/s", "horizontal speed limit", gt=0.05, le=5.0)
    hold_min_height_m: float = _f(
        0.5, "m", "below this height the descent no longer pauses when off-centre", ge=0.0, le=5.0
    )
    settle_s: float = _f(
        0.0,
        "s",
        "while the pad is in sight: the descent goes below hold_min_height_m only "
        "once the horizontal error has stayed within xy_tolerance_m this long, so the last part "
        "(below the camera's view) starts settled, not mid-swing; it waits at that height until then "
        "(0 = off)",
        ge=0.0,
        le=10.0,
    )
    touchdown_height_m: float = _f(
        0.15,
        "m",
        "below this height only the vertical command remains (ArduCopter never reports "
        "ON_GROUND while a horizontal velocity is commanded on the ground; measured on its SITL); "
        "negative: the horizontal error is closed until the autopilot reports the touchdown",
        ge=-1.0,
        le=2.0,
    )
    xy_integral_gain_1_s2: float = _f(
        0.0,
        "1/s^2",
        "horizontal speed per metre-second of accumulated error, which takes out what "
        "the autopilot's velocity loop leaves (its velocity-estimate bias; not in the papers; 0 = off)",
        ge=0.0,
        le=20.0,
    )
    xy_integral_max_m_s: float = _f(0.5, "m/s", "largest horizontal speed the integral term may add", ge=0.0, le=3.0)
    contact_time_s: float = _f(
        0.0,
        "s",
        "ground contact: once the vehicle, descending, has sunk slower than a quarter of the commanded "
        "descent this long within 2 m of the ground (by the estimate), only the descent is commanded (as below "
        "touchdown_height_m) and the touchdown is judged where the contact was, not where the "
        "autopilot's estimate has drifted to by the time its land detector fires (PX4 SIH: 3 s, "
        "0.4 m; 0 = off)",
        ge=0.0,
        le=2.0,
    )
    xy_accel_feedforward: float = _f(
        0.0,
        "-",
        "share of the horizontal command's rate of change (its proportional and integral "
        "terms on the estimated velocity and error) sent with it as an acceleration, so the autopilot "
        "answers without its velocity loop's lag (not in the papers; 0 = velocity only)",
        ge=0.0,
        le=1.0,
    )


#: ``[mission]`` keys of older files -> their key in ``[mission.descent]``
MISSION_OLD_DESCENT_KEYS = {f"landing_{k}": k for k in DescentConfig.model_fields}


class RangefinderConfig(_Section):
    """The autopilot's downward rangefinder (DISTANCE_SENSOR) in the final descent and for the
    touchdown: ``[mission.rangefinder]`` (companion.estimation.rangefinder, docs/rangefinder.md).
    A reading is used only when fresh, within the sensor's range, looking down, level enough, and
    consistent with the estimate's height; then the descent's height above the ground is the
    estimate's corrected by the rangefinder."""

    enabled: bool = _f(
        False,
        "-",
        "ask the autopilot for DISTANCE_SENSOR and fly the final descent and judge the ground contact on its "
        "height (off: the estimate's height alone, as before)",
    )
    max_age_s: float = _f(
        0.5, "s", "a reading older than this is not used (PX4 SIH, ArduCopter: 10 Hz)", gt=0.0, le=5.0
    )
    max_jump_m: float = _f(
        0.5,
        "m",
        "a reading whose offset from the estimate's height moved more than this from the reading before, or "
        "from the last one used while it is held, is rejected (a leg, the parcel or a failed sensor seen)",
        gt=0.0,
        le=10.0,
    )
    max_disagreement_m: float = _f(
        3.0,
        "m",
        "a reading this far from the estimate's height is rejected (the estimate drifted up to 1.7 m on PX4 SIH)",
        gt=0.0,
        le=50.0,
    )
    below_height_m: float = _f(
        4.0, "m", "used only below this height above the ground (by the estimate)", gt=0.0, le=100.0
    )
    max_tilt_deg: float = _f(
        25.0,
        "deg",
        "not used while the vehicle is tilted more than this (the beam hits the ground off-centre)",
        ge=0.0,
        le=60.0,
    )
    min_quality_pct: int = _f(
        1, "%", "a reading whose reported signal quality is below this is rejected (not reported: taken)", ge=0, le=100
    )
    hold_s: float = _f(
        2.0,
        "s",
        "the correction of the last reading used is kept this long when none passes (below the sensor's minimum "
        "range at the ground: ArduCopter's RNGFND1_MIN, 0.2 m)",
        ge=0.0,
        le=10.0,
    )


class MissionConfig(_Section):
    """Delivery path (delivery section 4.1) and vector field (delivery eqs 16-19)."""

    height_m: float = _f(45.0, "m", "cruise height h above the pad (F_I z)", gt=2.0, le=120.0)
    arc_radius_m: float = _f(6.0, "m", "radius r of the two transition arcs", gt=0.0, le=50.0)
    sector_speed_m_s: tuple[float, float, float, float, float] = _f(
        (2.0, 3.0, 5.0, 2.0, 1.5), "m/s", "reference speed v_i in sectors S1..S5", min_length=5
    )
    convergence_gain: float = _f(1.0, "1/m", "k_f: vector field convergence weight", gt=0.0, le=20.0)
    link_loss_resume_modes: tuple[str, ...] = _f(
        ("hold", "position"),
        "-",
        "after a link loss in flight, modes found on reconnect that count as the autopilot's own "
        "offboard-loss failsafe (PX4 COM_OBL_RC_ACT = 0 goes to position, measured) and resume the "
        "mission; any other mode is the pilot's. A pilot who picks one of these during the outage gets "
        "autonomy back on reconnect: list only your autopilot's failsafe mode",
    )
    field_lookahead_s: float = _f(
        0.0,
        "s",
        "evaluate the vector field where the vehicle will be this much later (position + velocity x "
        "lookahead), making up for the autopilot's velocity-loop lag at the arcs (not in the paper; "
        "0 = the paper's field at the current position; ~0.5 s for PX4 / ArduCopter)",
        ge=0.0,
        le=3.0,
    )
    autopilot_accel_xy_m_s2: float = _f(
        0.0,
        "m/s^2",
        "the autopilot's horizontal acceleration limit for velocity setpoints (ArduCopter WPNAV_ACCEL, "
        "PX4 MPC_ACC_HOR): the field's speed is kept within it at the arcs and before slower sectors "
        "(not in the papers; 0 = off, the paper's speeds)",
        ge=0.0,
        le=20.0,
    )
    autopilot_accel_z_m_s2: float = _f(
        0.0,
        "m/s^2",
        "the autopilot's vertical acceleration limit (ArduCopter WPNAV_ACCEL_Z, PX4 MPC_ACC_UP_MAX / "
        "MPC_ACC_DOWN_MAX), used on the climb, the descents and the arcs (0 = off)",
        ge=0.0,
        le=20.0,
    )
    velocity_bias_tau_s: float = _f(
        0.0,
        "s",
        "correct every setpoint by the autopilot's velocity-estimate bias, seen as the low-passed "
        "difference between the rate of its position estimate and its reported velocity, with this "
        "time constant (not in the papers; PX4 SIH: 1 s; 0 = off, setpoints as the field gives them)",
        ge=0.0,
        le=10.0,
    )
    velocity_bias_source: Literal["autopilot", "fusion"] = _f(
        "autopilot",
        "-",
        "what the velocity bias is measured against: the autopilot's own position, or (fusion) the "
        "landing fusion's camera / UWB position once it has pad data. PX4 v1.16 SIH's position drifts "
        "with its biased velocity (up to 20 cm from the truth in 3 s near the ground), so its rate shows "
        "only part of the bias",
    )
    velocity_bias_max_m_s: float = _f(
        1.0, "m/s", "largest velocity-bias correction applied to a setpoint", ge=0.0, le=3.0
    )
    takeoff_alt_m: float = _f(3.0, "m", "autopilot takeoff height before the field takes over", gt=0.5, le=20.0)
    final_descent_alt_m: float = _f(
        3.0, "m", "height above ground where the descent slows to land speed", gt=0.2, le=20.0
    )
    land_speed_m_s: float = _f(0.5, "m/s", "final descent speed", gt=0.05, le=2.0)
    descent: DescentConfig = Field(default_factory=DescentConfig)
    rangefinder: RangefinderConfig = Field(default_factory=RangefinderConfig)
    release_time_s: float = _f(2.0, "s", "time the payload actuator needs to release", ge=0.0, le=30.0)
    abort_hold_s: float = _f(5.0, "s", "abort: hold this long, then land", ge=0.0, le=120.0)
    ready_timeout_s: float = _f(60.0, "s", "preflight: wait this long for a healthy vehicle", gt=0.0, le=600.0)
    takeoff_timeout_s: float = _f(60.0, "s", "takeoff must reach its height within this time", gt=0.0, le=600.0)
    touchdown_timeout_s: float = _f(
        30.0,
        "s",
        "landing: fall back to the autopilot's LAND after this long below final descent height",
        gt=0.0,
        le=600.0,
    )
    estimate_timeout_s: float = _f(1.5, "s", "abort if the state estimate is older than this", gt=0.0, le=10.0)
    estimate_predict_max_s: float = _f(
        0.25,
        "s",
        "guidance carries the state estimate forward to its tick at the estimate's velocity when it "
        "is at most this old (the autopilot's position stream at 5-10 Hz leaves it 0.1-0.2 s behind); "
        "0: off. Must be < estimate_timeout_s",
        ge=0.0,
        le=1.0,
    )
    return_home: bool = _f(True, "-", "take off again after the release and fly home")
    return_from_landing_point: bool = _f(
        True,
        "-",
        "plan the way home from where the vehicle landed (the pad as found) instead of flying the "
        "outbound path back from the configured pad (the paper's flight)",
    )
    on_release_failure: Literal["return", "stay"] = _f(
        "return",
        "-",
        "when the autopilot refuses or fails the release: fly home with the parcel (return) or stay "
        "disarmed on the pad (stay); the mission reports the delivery as failed either way",
    )
    delivery: Literal["land", "winch"] = _f(
        "land",
        "-",
        "how the parcel is delivered: land (land on the pad, release, take off again) or winch (hover over the "
        "locked pad at winch.hover_height_m, lower the parcel on the autopilot's winch, release, reel in, fly "
        "home without landing; docs/winch.md)",
    )
    pad: PadConfig = Field(default_factory=lambda: PadConfig(north_m=70.0, east_m=71.0))
    alternate_pad: PadConfig | None = _f(
        None,
        "-",
        "a second pad to divert to when the first cannot be locked (landing.policy.fallback); none by default",
    )
    destination: Literal["params", "autopilot_mission"] = _f(
        "params",
        "-",
        "where the pad comes from: params (mission.pad and mission.alternate_pad here) or autopilot_mission "
        "(the mission the operator uploaded to the autopilot from the GCS, downloaded after connecting, before "
        "arming: a NAV_PAYLOAD_PLACE, or a waypoint or landing followed by a gripper release; docs/gcs.md)",
    )

    @model_validator(mode="before")
    @classmethod
    def _old_descent_keys(cls, data: Any) -> Any:
        return read_moved_keys(data, MISSION_OLD_DESCENT_KEYS, "mission", "descent")

    @model_validator(mode="after")
    def _geometry(self) -> MissionConfig:
        if self.arc_radius_m >= self.height_m:
            raise ValueError(
                f"arc_radius_m ({self.arc_radius_m}) must be < height_m ({self.height_m}): "
                "the arcs must fit below the cruise height"
            )
        for i, v in enumerate(self.sector_speed_m_s, start=1):
            if not (math.isfinite(v) and 0.0 < v <= 20.0):
                raise ValueError(f"sector_speed_m_s[{i - 1}] (v{i}) = {v}: must be in (0, 20] m/s")
        if self.takeoff_alt_m >= self.height_m - self.arc_radius_m:
            raise ValueError(
                f"takeoff_alt_m ({self.takeoff_alt_m}) must be below height_m - arc_radius_m "
                f"({self.height_m - self.arc_radius_m}), the top of the vertical section"
            )
        return self

    @field_validator("link_loss_resume_modes")
    @classmethod
    def _resume_modes(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        allowed = ("manual", "position", "hold", "takeoff", "land", "rtl", "mission", "unknown")
        bad = [m for m in v if m not in allowed]
        if bad:
            raise ValueError(f"{bad}: expected modes among {allowed} (offboard is ours, never a failsafe)")
        return v


class PayloadConfig(_Section):
    """How the parcel is released through the autopilot (the ``autopilot`` payload plugin)."""

    release: Literal["gripper", "servo", "actuator"] = _f(
        "gripper",
        "-",
        "gripper: MAV_CMD_DO_GRIPPER (ArduPilot GRIP_ENABLE = 1; PX4 payload deliverer); servo: "
        "MAV_CMD_DO_SET_SERVO (ArduPilot; PX4 answers UNSUPPORTED); actuator: MAV_CMD_DO_SET_ACTUATOR "
        "(PX4: an output whose function is 'Peripheral via Actuator Set N')",
    )
    gripper_instance: int = _f(1, "-", "gripper instance (DO_GRIPPER param 1)", ge=1, le=8)
    servo_channel: int = _f(9, "-", "servo output for release = servo (ArduPilot SERVOn)", ge=1, le=32)
    servo_pwm_us: int = _f(1900, "us", "PWM that opens the release servo", ge=800, le=2200)
    actuator_index: int = _f(1, "-", "PX4 actuator set index for release = actuator", ge=1, le=6)
    actuator_value: float = _f(1.0, "-", "PX4 actuator value that opens the release (-1..1)", ge=-1.0, le=1.0)


class WinchCameraConfig(_Section):
    """The downward camera judges the parcel down (docs/winch.md): an ArUco tag printed on the
    parcel's top is found in the frames while the line pays out, and the parcel's bottom is placed
    above the pad from the tag and the fused pose."""

    enabled: bool = _f(
        False,
        "-",
        "judge the parcel down with the camera: at the line's full length the parcel's bottom must be seen within "
        "down_tolerance_m of the pad, else no release, reel in, home with the parcel",
    )
    tag_dict: str = _f("DICT_4X4_50", "-", "the ArUco dictionary of the tag on the parcel's top")
    tag_id: int = _f(7, "-", "the tag's id in tag_dict (not one of the pad's own markers)", ge=0, le=999)
    tag_size_m: float = _f(0.2, "m", "the tag's side (its black border's outer edge)", gt=0.0, le=2.0)
    parcel_height_m: float = _f(
        0.25, "m", "the tag's height above the parcel's bottom (the parcel's height)", ge=0.0, le=3.0
    )
    down_tolerance_m: float = _f(
        0.15,
        "m",
        "the parcel counts as down when its bottom is seen within this of the pad (the fused height's error and "
        "the tag's range error at the hover height)",
        gt=0.0,
        le=2.0,
    )
    confirm_s: float = _f(
        0.5, "s", "the parcel must be seen down this long, every sighting within down_tolerance_m", ge=0.0, le=10.0
    )
    wait_s: float = _f(
        4.0,
        "s",
        "at the line's full length, wait this long for the camera to see the parcel down; then no release (caught, "
        "hanging short, or not seen), reel in, home with the parcel",
        gt=0.0,
        le=60.0,
    )
    stale_s: float = _f(0.5, "s", "a sighting older than this does not count", gt=0.0, le=10.0)

    @field_validator("tag_dict")
    @classmethod
    def _known_dictionary(cls, v: str) -> str:
        import cv2

        if not (v.startswith("DICT_") and hasattr(cv2.aruco, v)):
            raise ValueError(f"{v!r}: not a cv2.aruco dictionary name (e.g. 'DICT_4X4_50')")
        return v


class WinchConfig(_Section):
    """Winch delivery (mission.delivery = "winch"): the autopilot's winch (MAV_CMD_DO_WINCH) lowers
    the parcel from a hover over the locked pad (docs/winch.md)."""

    instance: int = _f(1, "-", "winch instance (DO_WINCH param 1; ArduCopter has one and ignores it)", ge=1, le=8)
    hover_height_m: float = _f(
        5.0, "m", "height above the pad the vehicle holds while the parcel is lowered", ge=1.0, le=30.0
    )
    slack_m: float = _f(
        0.3,
        "m",
        "line paid out beyond the hover height, so the parcel stands on the pad with the line slack before the release",
        ge=0.0,
        le=5.0,
    )
    payout_rate_m_s: float = _f(
        0.5,
        "m/s",
        "line payout rate asked for (DO_WINCH param 4; ArduCopter's length control drives at up to "
        "WINCH_RATE_MAX: set it to this rate)",
        gt=0.0,
        le=5.0,
    )
    reel_rate_m_s: float = _f(0.5, "m/s", "line reel-in rate asked for (DO_WINCH param 4)", gt=0.0, le=5.0)
    payout_timeout_s: float = _f(
        30.0,
        "s",
        "the line must reach the hover height plus slack within this time after the payout command, else the "
        "parcel is reeled back in and flown home",
        gt=0.0,
        le=600.0,
    )
    reel_timeout_s: float = _f(
        30.0,
        "s",
        "the line must be back in (winch.reeled_in_m) within this time, else the vehicle flies home saying so",
        gt=0.0,
        le=600.0,
    )
    wind_drift_s_m: float = _f(
        0.0,
        "s/m",
        "the parcel's steady drift downwind per metre of line per m/s of wind (its linear drag per unit mass over "
        "g; 0.03 for 0.3 1/s): the hover moves upwind by this x hover_height_m x the autopilot's wind estimate, "
        "so the parcel lands on the pad (0: hover over the pad's centre)",
        ge=0.0,
        le=0.5,
    )
    wind_filter_s: float = _f(
        3.0, "s", "time constant of the low-pass on the wind estimate the hover correction uses", gt=0.0, le=60.0
    )
    reeled_in_m: float = _f(0.1, "m", "the line counts as reeled in at or below this length", ge=0.0, le=2.0)
    length_tolerance_m: float = _f(
        0.1, "m", "the line counts as paid out within this of the hover height plus slack", gt=0.0, le=2.0
    )
    settle_s: float = _f(
        2.0, "s", "hold over the pad within the tolerances this long before the payout starts", ge=0.0, le=60.0
    )
    xy_tolerance_m: float = _f(
        0.2, "m", "the payout starts only this close to the locked pad's centre (horizontally)", gt=0.0, le=5.0
    )
    reel_check_s: float = _f(
        0.0,
        "s",
        "watch the reel-in: over each this long the line (WINCH_STATUS) must come in by half of reel_rate_m_s x "
        "this (or to reeled_in_m) and the winch must report itself healthy, else the line is jammed: a CRITICAL "
        "event, reel_retries more tries, then the vehicle lands where it is (0: off; the reel-in gets "
        "reel_timeout_s, then home as it is)",
        ge=0.0,
        le=60.0,
    )
    reel_retries: int = _f(
        1, "-", "with reel_check_s: reel-in tries after a jam before the vehicle lands where it is", ge=0, le=5
    )
    status_timeout_s: float = _f(
        3.0,
        "s",
        "the winch's line length (WINCH_STATUS) must be younger than this while the line moves, else the winch "
        "counts as failed",
        gt=0.0,
        le=60.0,
    )
    tension_sensing: bool = _f(
        False,
        "-",
        "the winch reports the line's tension (WINCH_STATUS.tension: a winch with a load cell): the parcel counts "
        "as down when the line goes slack, a line still taut at its full length is a parcel hanging short of the "
        "ground (no release), and after the release the line must come up light (false: the line length alone, "
        "as for ArduCopter's PWM winch, which reports no tension)",
    )
    slack_tension_kg: float = _f(
        0.1,
        "kg",
        "with tension_sensing: the line counts as slack (nothing hangs on it) below this tension",
        gt=0.0,
        le=20.0,
    )
    snag_margin_m: float = _f(
        1.0,
        "m",
        "with tension_sensing: a line going slack this much short of hover_height_m is a parcel caught on the way "
        "down (a branch, a roof edge): no release, reel in, home with it",
        gt=0.0,
        le=30.0,
    )
    light_check_m: float = _f(
        0.6,
        "m",
        "with tension_sensing: after the release the first this-much of line reeled in must stay slack, else the "
        "parcel is still on the hook and comes home (more than slack_m: the slack is taken up first)",
        gt=0.0,
        le=10.0,
    )

    camera: WinchCameraConfig = Field(default_factory=WinchCameraConfig)

    @model_validator(mode="after")
    def _light_check_past_the_slack(self) -> WinchConfig:
        if self.tension_sensing and self.light_check_m <= self.slack_m:
            raise ValueError(
                f"light_check_m ({self.light_check_m}) must be > slack_m ({self.slack_m}): until the slack is "
                "reeled in, even a parcel still on the hook leaves the line slack"
            )
        return self


class LimitsConfig(_Section):
    """Clamps applied to every setpoint before it leaves (safety contract, docs/architecture.md)."""

    max_horizontal_speed_m_s: float = _f(8.0, "m/s", "horizontal speed limit", gt=0.0, le=30.0)
    max_climb_m_s: float = _f(3.0, "m/s", "climb rate limit", gt=0.0, le=10.0)
    max_descent_m_s: float = _f(2.0, "m/s", "descent rate limit", gt=0.0, le=10.0)
    max_yaw_rate_deg_s: float = _f(60.0, "deg/s", "yaw rate limit", gt=0.0, le=360.0)
    max_horizontal_accel_m_s2: float = _f(
        2.0,
        "m/s^2",
        "largest horizontal acceleration fed forward with a velocity setpoint (mission.descent.xy_accel_feedforward)",
        gt=0.0,
        le=10.0,
    )
    geofence_radius_m: float = _f(500.0, "m", "max horizontal distance from home", gt=10.0, le=20000.0)
    geofence_max_alt_m: float = _f(120.0, "m", "max height above home", gt=5.0, le=1000.0)


class FencePolygonConfig(_Section):
    """One fence polygon: its vertices as [latitude, longitude] pairs in order, closed implicitly."""

    vertices_deg: tuple[tuple[float, float], ...] = _f(
        ...,
        "deg",
        "vertices as [lat, lon] pairs (WGS-84), in order around the polygon; the last joins the first "
        "(a repeated first vertex at the end is dropped)",
    )

    @field_validator("vertices_deg")
    @classmethod
    def _polygon(cls, v: tuple[tuple[float, float], ...]) -> tuple[tuple[float, float], ...]:
        if len(v) > 1 and v[0] == v[-1]:
            v = v[:-1]
        for i, (lat, lon) in enumerate(v):
            if not (math.isfinite(lat) and -90.0 <= lat <= 90.0):
                raise ValueError(f"vertex {i} latitude {lat}: must be in [-90, 90] deg")
            if not (math.isfinite(lon) and -180.0 <= lon <= 180.0):
                raise ValueError(f"vertex {i} longitude {lon}: must be in [-180, 180] deg")
        problem = polygon_problem([(lon, lat) for lat, lon in v])
        if problem is not None:
            raise ValueError(f"not a closed simple polygon: {problem}")
        return v

    def contains(self, lat_deg: float, lon_deg: float) -> bool:
        """Whether the point lies inside (or on) the polygon, in the lat/lon plane."""
        return point_in_polygon((lon_deg, lat_deg), [(lon, lat) for lat, lon in self.vertices_deg])


class FenceConfig(_Section):
    """The geofence (docs/go-no-go.md): the planned path must lie inside, and the autopilot keeps it
    as its own fence (uploaded with the MAVLink fence protocol, read back before arming)."""

    enabled: bool = _f(False, "-", "check the planned path against the fence and refuse a delivery that leaves it")
    inclusion: tuple[FencePolygonConfig, ...] = _f(
        (),
        "-",
        "[[fence.inclusion]] polygons: the vehicle must stay inside every one (ArduPilot's rule; PX4 asks "
        "for one of them) - at least one when enabled",
    )
    exclusion: tuple[FencePolygonConfig, ...] = _f((), "-", "[[fence.exclusion]] polygons: the vehicle must stay out")
    max_alt_rel_m: float | None = _f(
        None,
        "m",
        "altitude ceiling above home (none: no ceiling); the autopilot's own ceiling (ArduPilot FENCE_ALT_MAX, "
        "PX4 GF_MAX_VER_DIST) is checked by preflight",
        gt=2.0,
        le=1000.0,
    )
    margin_m: float = _f(
        5.0,
        "m",
        "the planned path must keep this far inside every fence edge and below the ceiling (path following error, "
        "the autopilot's fence reaction)",
        ge=0.0,
        le=500.0,
    )
    upload: bool = _f(
        True,
        "-",
        "upload the polygons to the autopilot as its own fence (MAV_MISSION_TYPE_FENCE) and read them back before "
        "arming: the autopilot's fence action holds if the companion dies",
    )

    @model_validator(mode="after")
    def _has_inclusion(self) -> FenceConfig:
        if self.enabled and not self.inclusion:
            raise ValueError("fence.enabled needs at least one [[fence.inclusion]] polygon")
        return self

    def problem_at(self, lat_deg: float, lon_deg: float, what: str) -> str | None:
        """Why ``what`` at (lat, lon) is not allowed by the polygons, or None."""
        for i, p in enumerate(self.inclusion):  # inside every one: ArduPilot's rule, stricter than PX4's
            if not p.contains(lat_deg, lon_deg):
                return f"{what} ({lat_deg:.7f}, {lon_deg:.7f}) is outside inclusion polygon {i}"
        for i, p in enumerate(self.exclusion):
            if p.contains(lat_deg, lon_deg):
                return f"{what} ({lat_deg:.7f}, {lon_deg:.7f}) is inside exclusion polygon {i}"
        return None


class GoNoGoConfig(_Section):
    """Go / no-go before and during the flight (docs/go-no-go.md): the battery, the wind, and what the
    pre-flight check expects of the autopilot's own failsafes."""

    battery_check: bool = _f(
        False,
        "-",
        "refuse a take-off without the charge for the round trip, and abandon the delivery and fly home once the "
        "charge left falls to what the way home needs plus battery_reserve_pct (the autopilot's remaining %)",
    )
    battery_reserve_pct: float = _f(
        20.0, "%", "charge that must be left on landing at home, on top of what the way home takes", ge=0.0, le=80.0
    )
    battery_use_pct_per_s: float = _f(
        0.0,
        "%/s",
        "the vehicle's battery use in flight (0: measured in flight from the autopilot's remaining %, once "
        "battery_measure_s have been flown; until then the battery check waits)",
        ge=0.0,
        le=10.0,
    )
    battery_measure_s: float = _f(
        30.0, "s", "flight time before the measured use counts (the remaining % moves in 1 % steps)", ge=5.0, le=600.0
    )
    wind_limit_m_s: float = _f(
        0.0,
        "m/s",
        "largest wind the autopilot estimates (ArduPilot WIND, PX4 WIND_COV) for a take-off; a return home when it "
        "is exceeded in flight (0: off)",
        ge=0.0,
        le=30.0,
    )
    wind_exceed_s: float = _f(
        3.0,
        "s",
        "in flight, the wind estimate must stay above wind_limit_m_s this long before the return (a gust passes)",
        ge=0.0,
        le=120.0,
    )
    wind_max_age_s: float = _f(
        3.0, "s", "a wind estimate older than this is none (before take-off the check waits for one)", gt=0.0, le=60.0
    )
    remote_id_required: bool = _f(
        False,
        "-",
        "preflight expects the autopilot to refuse arming without Remote ID (PX4 COM_ARM_ODID = 2, ArduPilot "
        "DID_ENABLE = 1); false: the setting is only reported",
    )


class RuntimeConfig(_Section):
    """Task rates (floors, not ceilings: docs/architecture.md) and watchdogs."""

    guidance_rate_hz: float = _f(20.0, "Hz", "guidance and mission rate", ge=20.0, le=200.0)
    setpoint_rate_hz: float = _f(
        20.0,
        "Hz",
        "least rate of setpoints to the autopilot (PX4 needs > 2 Hz): each guidance tick sends its own, the "
        "stream resends the latest when none was sent for this period",
        ge=5.0,
        le=200.0,
    )
    guidance_on_marker: bool = _f(
        True,
        "-",
        "tick guidance as soon as a camera observation of the pad is fused while the fused estimate steers, so the "
        "setpoint that uses it leaves at once instead of at the next guidance_rate_hz tick (false: fixed rate only)",
    )
    vision_cpu_budget: float = _f(
        0.0,
        "core",
        "share of one core the landing camera's detector may use: each detection's own CPU time sets when the "
        "next may start (cost / budget later), the frames between are skipped; for boards whose core is several "
        "times slower than a server's (docs/cpu-budget.md). 0: every frame the camera offers",
        ge=0.0,
        le=8.0,
    )
    vision_thread_nice: int = _f(
        0,
        "-",
        "nice value the detector's executor thread sets for itself (Linux, per thread; 0-19, higher yields more): "
        "with a core shared by the detector and the loop that runs guidance and the setpoint stream, the loop "
        "gets the CPU first when both are ready. 0: unchanged",
        ge=0,
        le=19,
    )
    realtime_priority: int = _f(
        0,
        "-",
        "Linux SCHED_RR priority of the companion's threads for the flight: the event loop's (guidance, fusion, "
        "the setpoint stream) and those it starts (the autopilot link's, telemetry's, the logs' writers), the "
        "detector's one lower (vision_thread_nice then does not apply); they preempt every normal-policy thread "
        "when they wake, so exposure -> setpoint holds on a loaded core. The logging process stays at the normal "
        "policy. Needs CAP_SYS_NICE or RLIMIT_RTPRIO at least this (docs/flying.md); where refused, a warning and "
        "the normal policy. 0: the normal policy",
        ge=0,
        le=98,
    )
    opencv_threads: int = _f(
        1,
        "-",
        "threads OpenCV's parallel loops may use in this process (cv2.setNumThreads; 1: each call on its calling "
        "thread, the detector's executor; -1: OpenCV's default, one per CPU, whose spinning pool cost 7.5 % of one "
        "core on 640x480 frames in bench app)",
        ge=-1,
        le=64,
    )
    setpoint_stale_s: float = _f(
        0.5, "s", "stop streaming if the control task has not refreshed the setpoint for this long", gt=0.05, le=5.0
    )
    loop_stall_s: float = _f(
        0.5,
        "s",
        "the control loop's liveness (docs/companion-death.md): a watchdog thread, off the event loop, stops every "
        "heartbeat and setpoint the companion sends (the backend's GCS heartbeat, its component's, MAVSDK's re-sent "
        "setpoint) when no guidance tick came for this long, so the autopilot fails safe within its own timeout "
        "(ArduCopter FS_GCS_TIMEOUT, PX4 COM_OF_LOSS_T) as if the companion had died; they resume when the loop ticks "
        "again. 0.5 s: ten guidance periods, above the slowest tick seen on a capped board (~0.1 s), and small beside "
        "the autopilots' 1-5 s timeouts, which it adds to",
        ge=0.2,
        le=2.0,
    )
    link_timeout_s: float = _f(
        1.0,
        "s",
        "no message from the autopilot for this long is a lost link (so is a heartbeat older than 3.5 s on "
        "ArduPilot, or MAVSDK's own heartbeat timeout on PX4, while other telemetry still arrives)",
        gt=0.1,
        le=30.0,
    )
    connect_timeout_s: float = _f(
        10.0, "s", "start-up: give up when no autopilot answers on the connection within this time", gt=0.0, le=600.0
    )
    log_rate_hz: float = _f(20.0, "Hz", "flight-log sampling rate of the shell state", gt=0.0, le=200.0)
    autopilot_attitude_rate_hz: float | None = _f(
        None,
        "Hz",
        "rate the companion asks the autopilot to stream its attitude and IMU at (ArduPilot: ATTITUDE, "
        "HIGHRES_IMU / RAW_IMU; PX4 through MAVSDK: ATTITUDE, ATTITUDE_QUATERNION, IMU); every message costs "
        "the link's decoding and fusion's prediction, so a slow board lowers it (docs/cpu-budget.md). Unset: "
        "ArduPilot 50 Hz, PX4 the rates of its MAVLink instance's mode",
        ge=5.0,
        le=200.0,
    )
    autopilot_position_rate_hz: float | None = _f(
        None,
        "Hz",
        "rate the companion asks the autopilot to stream its position and velocity at (LOCAL_POSITION_NED, "
        "GLOBAL_POSITION_INT). Unset: ArduPilot 30 Hz, PX4 the rates of its MAVLink instance's mode",
        ge=2.0,
        le=100.0,
    )
    autopilot_timesync_hz: float = _f(
        0.0,
        "Hz",
        "TIMESYNC requests per second to the autopilot, for the offset of its boot clock to the companion's, its "
        "jitter and round trip (ArduPilot: pymavlink; PX4: MavlinkDirect, MAVSDK's own timesync being internal "
        "to it; docs/clock.md); 0: off",
        ge=0.0,
        le=50.0,
    )
    autopilot_sample_time: Literal["receipt", "autopilot"] = _f(
        "receipt",
        "-",
        "the time of the autopilot's attitude and position samples: their receipt on the companion's clock, or "
        "(ArduPilot, with autopilot_timesync_hz > 0) their time_boot_ms mapped onto it through the TIMESYNC "
        "offset, the link's delay taken out (docs/clock.md)",
    )


class TelemetryCommandsConfig(_Section):
    """Commands from the ground (hold, return, land, abort). Off by default (safety contract, docs/architecture.md)."""

    enabled: bool = _f(False, "-", "accept authenticated ground commands")
    secret_file: str | None = _f(None, "-", "file holding the shared HMAC secret (>= 16 bytes)")
    window_s: float = _f(5.0, "s", "allowed clock difference for a command's timestamp", ge=0.1, le=300.0)
    max_nonces: int = _f(4096, "-", "replay-protection cache size", ge=16, le=1_000_000)
    rate_per_s: float = _f(2.0, "1/s", "signed requests a second each sender may send", ge=0.01, le=1000.0)
    burst: int = _f(10, "-", "signed requests a sender may send at once (its token bucket)", ge=1, le=10_000)
    max_requests_per_s: float = _f(
        50.0, "1/s", "requests of any sender read a second; beyond it refused unread", ge=1.0, le=100_000.0
    )

    @model_validator(mode="after")
    def _secret(self) -> TelemetryCommandsConfig:
        if self.enabled and not self.secret_file:
            raise ValueError("commands.enabled needs secret_file (a file with a shared secret of >= 16 bytes)")
        return self


class TelemetryConfig(_Section):
    """Ground telemetry over Eclipse Zenoh (companion/telemetry; key space companion/<vehicle_id>/...)."""

    enabled: bool = _f(True, "-", "publish telemetry (the demo publishes only with --telemetry)")
    zenoh_config: str = _f("zenoh_peer.toml", "-", "Zenoh session file: a path, or the name of a shipped params file")
    state_rate_hz: float = _f(20.0, "Hz", "state topic rate (newest sample kept)", ge=0.01, le=1000.0)
    estimate_rate_hz: float = _f(10.0, "Hz", "estimate topic rate", ge=0.01, le=1000.0)
    mission_rate_hz: float = _f(5.0, "Hz", "mission status rate (events are never dropped)", ge=0.01, le=1000.0)
    landing_rate_hz: float = _f(10.0, "Hz", "landing topic rate", ge=0.01, le=1000.0)
    health_rate_hz: float = _f(1.0, "Hz", "health topic rate", ge=0.01, le=1000.0)
    event_queue_size: int = _f(1024, "-", "bound of the never-drop event queue", ge=16, le=1_000_000)
    commands: TelemetryCommandsConfig = Field(default_factory=TelemetryCommandsConfig)


class PadLockPolicyConfig(_Section):
    """No release off the pad (docs/delivery-policy.md): the parcel is released only on a locked
    pad, and what the vehicle does, in order, when the pad is not locked."""

    require_pad_lock: bool = _f(
        True,
        "-",
        "release only on a locked pad (a camera or UWB observation younger than max_observation_age_s "
        "and the EKF's horizontal 1-sigma under max_horizontal_sigma_m, checked at the approach height and "
        "at touchdown); without pad sensors (landing.fusion = false, or neither camera nor UWB) no lock is "
        "possible and the parcel flies home. false: release wherever the vehicle lands, the paper's GPS-only "
        "baseline (delivery Fig. 15): an explicit opt-out, said in an event at each release",
    )
    max_observation_age_s: float = _f(
        2.0,
        "s",
        "the pad is locked while its newest accepted camera or UWB observation is younger (a camera alone "
        "loses the pad in the last ~0.7 m: 1.4 s at 0.5 m/s before touchdown)",
        gt=0.0,
        le=10.0,
    )
    max_horizontal_sigma_m: float = _f(
        0.25,
        "m",
        "the pad is locked while the EKF's horizontal position 1-sigma (largest axis) is under this",
        gt=0.001,
        le=5.0,
    )
    commit_height_m: float = _f(
        1.0,
        "m",
        "in the final descent, a lost lock above this height stops the descent (a try fails); below it the "
        "descent finishes and the touchdown check decides",
        ge=0.0,
        le=20.0,
    )
    reopen_grace_s: float = _f(
        1.0,
        "s",
        "in the final descent, while the camera or UWB keeps observing the pad (an observation within the "
        "last 0.5 s) but the EKF's 1-sigma is over max_horizontal_sigma_m (the EKF re-opened its "
        "covariance after ekf_gate_reset_after_rejections rejections, and the next accepted observation "
        "closes it again), the try fails only once this has lasted this long; 0: at once",
        ge=0.0,
        le=10.0,
    )
    approach_tolerance_m: float = _f(
        0.5,
        "m",
        "after a hold or search, the descent starts again only this close (horizontally) above the locked pad",
        gt=0.05,
        le=5.0,
    )
    hold_s: float = _f(5.0, "s", "step 1: hold at the approach height this long waiting for the lock", ge=0.0, le=120.0)
    search_height_m: float = _f(
        8.0,
        "m",
        "step 2: climb to this height above the pad for the search (higher: the camera sees more ground, "
        "the markers are smaller)",
        gt=1.0,
        le=60.0,
    )
    search_radius_m: float = _f(
        6.0,
        "m",
        "step 2: the search pattern (an expanding square around the configured pad) stays within this "
        "horizontal distance of it; 0 = no search",
        ge=0.0,
        le=50.0,
    )
    search_spacing_m: float = _f(
        2.5,
        "m",
        "step 2: distance between the legs of the expanding square: at most the ground the camera sees at "
        "search_height_m, so no ground between legs goes unseen",
        gt=0.5,
        le=30.0,
    )
    search_speed_m_s: float = _f(
        1.5,
        "m/s",
        "step 2: ground speed along the pattern: slow enough for the detector (motion blur, frames per metre)",
        gt=0.1,
        le=8.0,
    )
    search_dwell_s: float = _f(
        1.0, "s", "step 2: pause at each corner of the pattern (frames at rest)", ge=0.0, le=30.0
    )
    descent_tries: int = _f(
        2,
        "-",
        "step 3: descents tried (the first included) before the fallback; each failed one is followed by "
        "the hold and the search again",
        ge=1,
        le=10,
    )
    fallback: Literal["home", "alternate"] = _f(
        "home",
        "-",
        "step 4: home = fly home with the parcel and land there without releasing it; alternate = climb to "
        "mission.height_m, fly to mission.alternate_pad and land there under this same policy (lock, hold, "
        "search, tries), then home with the parcel if that fails too",
    )


class GcsConfig(_Section):
    """The companion as a MAVLink component the operator's GCS sees and commands (docs/gcs.md)."""

    enabled: bool = _f(
        True,
        "-",
        "speak as a MAVLink component of our own on the autopilot link: heartbeat, mission events as "
        "STATUSTEXT, ONBOARD_COMPUTER_STATUS, hold/return/land COMMAND_LONGs with COMMAND_ACK",
    )
    component_id: int = _f(
        191, "-", "our MAVLink component id (191 = MAV_COMP_ID_ONBOARD_COMPUTER; not the autopilot's 1)", ge=2, le=254
    )
    system_id: int = _f(
        0,
        "-",
        "our MAVLink system id; 0 = the vehicle's (ArduPilot: as it heartbeats; PX4: 1, MAVSDK's identity is "
        "fixed before the vehicle answers, so set it when MAV_SYS_ID is not 1)",
        ge=0,
        le=255,
    )
    status_rate_hz: float = _f(1.0, "Hz", "ONBOARD_COMPUTER_STATUS rate", ge=0.1, le=10.0)
    accept_commands: bool = _f(
        True,
        "-",
        "act on hold, return and land COMMAND_LONGs addressed to our component (false: answered DENIED)",
    )
    command_system_ids: tuple[int, ...] = _f(
        (255,),
        "-",
        "the MAVLink system ids whose COMMAND_LONGs our component acts on (255: QGroundControl's, Mission "
        "Planner's and MAVProxy's default); any other sender's are dropped unanswered, counted and logged, as "
        "are unsigned ones on a signed ArduPilot link (docs/gcs.md, Who may command it)",
        min_length=1,
    )

    @field_validator("command_system_ids")
    @classmethod
    def _command_ids(cls, v: tuple[int, ...]) -> tuple[int, ...]:
        bad = [i for i in v if not 1 <= i <= 255]
        if bad:
            raise ValueError(f"{bad}: expected MAVLink system ids 1..255")
        return v


class EkfConfig(_Section):
    """The delivery EKF's noise and gating (delivery eqs 5-15; 1-sigma values): ``[landing.ekf]``,
    taken as it is by :class:`companion.estimation.ekf.DeliveryEkf`. A measurement's sigma grows
    with the height h above the pad: sigma = sigma0 + gain * h; Q_f (eq 6) is built from
    random-walk densities: Q_f = diag(sigma^2) * dt."""

    input_velocity_sigma_m_s: float = _f(0.3, "m/s", "Q_u (eq 6): noise of the velocity input", gt=0.0, le=10.0)
    input_rate_sigma_rad_s: float = _f(0.02, "rad/s", "Q_u (eq 6): noise of the body-rate input", gt=0.0, le=5.0)
    position_process_sigma_m_per_sqrt_s: float = _f(
        0.05,
        "m/sqrt(s)",
        "Q_f (eq 6) position random walk: how fast the autopilot's velocity error can carry the position "
        "away between pad observations. 0.05 suits an autopilot whose velocity estimate is good (ArduCopter "
        "SITL, the embedded simulator); PX4 v1.16 SIH needs ~0.3 (its velocity estimate was measured "
        "0.5 m/s off for seconds near the ground)",
        gt=0.0,
        le=5.0,
    )
    angle_process_sigma_rad_per_sqrt_s: float = _f(
        0.01, "rad/sqrt(s)", "Q_f (eq 6) attitude random walk", gt=0.0, le=5.0
    )
    gps_bias_process_sigma_m_per_sqrt_s: float = _f(
        0.01, "m/sqrt(s)", "Q_f (eq 6) GPS-bias random walk", gt=0.0, le=5.0
    )
    gyro_bias_process_sigma_rad_s_per_sqrt_s: float = _f(
        0.0005, "rad/s/sqrt(s)", "Q_f (eq 6) gyro-bias random walk", gt=0.0, le=1.0
    )
    initial_position_sigma_m: float = _f(10.0, "m", "initial position uncertainty", gt=0.0, le=1000.0)
    initial_angle_sigma_rad: float = _f(0.5, "rad", "initial attitude uncertainty", gt=0.0, le=10.0)
    initial_gps_bias_sigma_m: float = _f(5.0, "m", "initial GPS-bias uncertainty", gt=0.0, le=1000.0)
    initial_gyro_bias_sigma_rad_s: float = _f(0.05, "rad/s", "initial gyro-bias uncertainty", gt=0.0, le=10.0)
    sdk_position_sigma_m: float = _f(1.0, "m", "h_SDK (eq 12): the autopilot's (GPS) position", gt=0.0, le=100.0)
    sdk_position_sigma_gain_m_per_m: float = _f(
        0.0, "m/m", "h_SDK: growth of its position sigma with the height above the pad", ge=0.0, le=1.0
    )
    sdk_angle_sigma_rad: float = _f(0.03, "rad", "h_SDK (eq 12): the autopilot's attitude", gt=0.0, le=10.0)
    aruco_position_sigma_m: float = _f(
        0.02, "m", "h_ArUco (eqs 13-14): the marker's position in the camera", gt=0.0, le=10.0
    )
    aruco_position_sigma_gain_m_per_m: float = _f(
        0.01, "m/m", "h_ArUco: growth of its position sigma with the height above the pad", ge=0.0, le=1.0
    )
    aruco_roll_pitch_sigma_rad: float = _f(
        0.35, "rad", "h_ArUco: the marker's roll and pitch (a single marker's are noisy)", gt=0.0, le=10.0
    )
    aruco_yaw_sigma_rad: float = _f(0.05, "rad", "h_ArUco: the marker's yaw", gt=0.0, le=10.0)
    aruco_angle_sigma_gain_rad_per_m: float = _f(
        0.002, "rad/m", "h_ArUco: growth of its angle sigmas with the height above the pad", ge=0.0, le=1.0
    )
    aruco_max_height_m: float = _f(
        30.0, "m", "markers seen from higher above the pad are not fused (delivery 5.1)", gt=0.0, le=1000.0
    )
    uwb_position_sigma_m: float = _f(0.10, "m", "h_UWB (eq 15): a UWB fix's position", gt=0.0, le=10.0)
    uwb_position_sigma_gain_m_per_m: float = _f(
        0.01, "m/m", "h_UWB: growth of its sigma with the height above the pad", ge=0.0, le=1.0
    )
    uwb_scale_with_pdop: bool = _f(
        True,
        "-",
        "per-axis UWB sigma *= PDOP / sqrt(3) when the fix has one; a fix from coplanar anchors "
        "(vertical_weak) gets sigma * HDOP / sqrt(2) horizontally and sigma * VDOP vertically",
    )
    gating_enabled: bool = _f(True, "-", "chi-square innovation gate on every measurement")
    gate_probability: float = _f(0.9999, "-", "the gate's chi-square probability", gt=0.5, lt=1.0)
    gate_reset_after_rejections: int = _f(
        20,
        "-",
        "consecutive gate rejections of one sensor after which the EKF admits it is lost and re-opens "
        "the covariance the sensor disagrees with (SDK: the GPS bias, or p before xi; ArUco/UWB: p and "
        "the GPS bias) to the initial sigmas, counted as <sensor>.gate_resets (UWB at 10 Hz: 20 = 2 s); "
        "0: never",
        ge=0,
        le=1000,
    )
    max_step_s: float = _f(0.05, "s", "longer predictions are split into sub-steps of at most this", gt=0.0, le=1.0)
    min_variance: float = _f(1e-12, "-", "floor of every state variance (numerics)", gt=0.0, le=1e-3)


class DetectorConfig(_Section):
    """The pad detector's tuning (companion.vision.detector.PadDetector): ``[landing.detector]``."""

    err_ratio_threshold: float = _f(
        0.6, "-", "accept the best IPPE solution if err_best / err_second < this", gt=0.0, le=1.0
    )
    agree_angle_rad: float = _f(
        math.radians(2.0), "rad", "candidates closer than this are the same pose", gt=0.0, le=math.pi
    )
    prior_margin_rad: float = _f(
        math.radians(6.0), "rad", "a prior must prefer one candidate by this much", gt=0.0, le=math.pi
    )
    prior_max_age_s: float = _f(0.5, "s", "the previous accepted pose is a prior for this long", gt=0.0, le=60.0)
    max_tilt_rad: float = _f(
        math.radians(60.0), "rad", "tilt gate: the pad normal within this of the expected up", gt=0.0, le=math.pi
    )
    max_reprojection_error_px: float = _f(4.0, "px", "poses that reproject worse are rejected", gt=0.0, le=1000.0)
    roi_enabled: bool = _f(True, "-", "search a region of interest around the last sighting")
    roi_margin_frac: float = _f(
        0.35, "-", "margin around the last corners' box, a fraction of its size", gt=0.0, le=10.0
    )
    roi_min_margin_px: int = _f(24, "px", "the ROI's smallest margin", ge=0, le=10000)
    full_search_every: int = _f(30, "-", "a full-frame search at least every N frames", ge=1, le=100000)
    roi_predict_max_gap_s: float = _f(
        0.5,
        "s",
        "the ROI follows the pad's image motion (centre and scale rates from the last two frames that "
        "found it) over gaps up to this long; 0: the ROI stays where the pad was last seen",
        ge=0.0,
        le=60.0,
    )
    roi_target_marker_px: float = _f(90.0, "px", "large markers are searched at reduced resolution", gt=0.0, le=10000.0)
    min_marker_px: float = _f(12.0, "px", "smallest marker side searched for in a full frame", gt=0.0, le=10000.0)
    edge_refinement: bool = _f(True, "-", "corners from fitted border lines (refine_corners_by_edges)")
    min_pose_marker_px: float = _f(20.0, "px", "a lone marker smaller than this gives no pose", gt=0.0, le=10000.0)
    attitude_agree_rad: float = _f(
        math.radians(8.0),
        "rad",
        "with a measured attitude: a candidate's pad normal within this of the attitude's up agrees with it",
        gt=0.0,
        le=math.pi,
    )
    attitude_margin_rad: float = _f(
        math.radians(3.0),
        "rad",
        "when both candidates agree with the attitude, the closer normal wins only by this much (else the "
        "previous pose)",
        gt=0.0,
        le=math.pi,
    )
    attitude_resolution: bool = _f(True, "-", "use the attitude rule whenever the detector is given the attitude")


class MultilaterationConfig(_Section):
    """The UWB solver's settings (companion.uwb.multilateration.Multilaterator):
    ``[landing.multilateration]``."""

    max_range_m: float | None = _f(
        None,
        "m",
        "ranges longer than this are refused; none: the anchor layout's (10 m for the DWM1001)",
        gt=0.0,
        le=1000.0,
    )
    residual_threshold_m: float = _f(0.30, "m", "a range whose residual exceeds this is an outlier", gt=0.0, le=100.0)
    max_pdop: float = _f(
        20.0,
        "-",
        "the largest PDOP accepted; for coplanar anchors (whose vertical is weak by design) the same limit "
        "applies to the dilution in the anchors' plane (HDOP for anchors at one height)",
        gt=0.0,
        le=10000.0,
    )
    range_sigma_m: float = _f(
        0.10,
        "m",
        "the ranging noise (DWM1001 TWR: +-10 cm), used only to bound the reported VDOP of a fix at or near "
        "the anchors' plane, where the linearised VDOP diverges",
        gt=0.0,
        le=10.0,
    )
    max_iterations: int = _f(30, "-", "Gauss-Newton iterations per solve", ge=1, le=1000)
    step_tolerance_m: float = _f(1e-7, "m", "converged: the step is shorter than this", gt=0.0, le=1.0)
    max_subsets: int = _f(100, "-", "anchor subsets tried when outliers are sought", ge=1, le=100000)
    prefer_high_solution: bool = _f(
        True,
        "-",
        "two equally good solutions (exactly determined TDoA, mirror images): without a prior, take the one "
        "with the larger z (the tag flies above the anchors)",
    )
    seed: int = _f(0, "-", "seed of the subset sampling (deterministic)", ge=0, le=2**63 - 1)


class DropZoneConfig(_Section):
    """Is the drop zone clear (companion.vision.drop_zone, docs/drop-zone.md): ``[landing.drop_zone]``.

    Off by default: on, the downward camera's frames are also checked for an object on the pad
    (markers hidden, the pad-plane image unlike the printed pad) and motion in a margin around it,
    and an occupied pad stops the descent (the mission's drop-zone policy)."""

    enabled: bool = _f(False, "-", "check the pad and its margin for objects and motion before and during the descent")
    margin_m: float = _f(1.0, "m", "width of the margin around the pad watched for motion", gt=0.0, le=5.0)
    grid_m: float = _f(0.02, "m", "cell of the pad-plane warp the check compares", ge=0.005, le=0.1)
    window_m: float = _f(0.2, "m", "side of the windows compared with the printed pad (ZNCC)", ge=0.04, le=0.5)
    zncc_min: float = _f(
        0.45, "-", "a window correlating less than this with the printed pad differs from it", gt=-1.0, lt=1.0
    )
    min_texture: float = _f(
        0.2,
        "-",
        "windows of the printed pad with less contrast than this (std, white = 1) are not compared",
        gt=0.0,
        le=0.5,
    )
    raised_black_ratio: float = _f(
        0.3,
        "-",
        "a window unlike the print is an object only where its black is raised above this share of its "
        "contrast (a shadow scales black and white alike; an object covers the black with its own grey)",
        ge=0.0,
        le=10.0,
    )
    differing_area_m2: float = _f(
        0.008, "m^2", "a pad area this large unlike the printed pad is an object on it", gt=0.0, le=1.0
    )
    corroborated_area_m2: float = _f(
        0.003,
        "m^2",
        "with a marker hidden that had been seen and should be seen now, a differing area this large is an object",
        gt=0.0,
        le=1.0,
    )
    hidden_min_side_px: float = _f(
        30.0,
        "px",
        "a marker whose predicted side is at least this and which is not found counts as hidden",
        gt=0.0,
        le=10000.0,
    )
    min_px_per_cell: float = _f(
        0.5,
        "px",
        "below this many image pixels per grid cell at the pad (too high) the check abstains",
        gt=0.0,
        le=100.0,
    )
    min_visible_fraction: float = _f(
        0.6, "-", "the check abstains when less of the pad than this is in the frame", gt=0.0, le=1.0
    )
    max_shift_m: float = _f(
        0.16, "m", "registration search around the pose's pad position (a predicted pose's error)", ge=0.0, le=1.0
    )
    max_bend_m: float = _f(
        0.24,
        "m",
        "the registration's homography (ECC on the print, after the shift) may move a corner of the pad this far: "
        "a marker corner the detector misplaced bends the warp; 0: the shift alone",
        ge=0.0,
        le=1.0,
    )
    motion_baseline_s: float = _f(
        0.3, "s", "frames this far apart are differenced for motion in the margin", gt=0.0, le=5.0
    )
    motion_threshold: float = _f(
        30.0,
        "grey levels",
        "a margin cell changing by more than this (mean grey scaled to 128) moved",
        gt=0.0,
        le=255.0,
    )
    motion_area_m2: float = _f(0.025, "m^2", "a moving region this large in the margin is motion", gt=0.0, le=10.0)
    votes: int = _f(5, "-", "frames of evidence the verdict looks back over (hysteresis)", ge=1, le=100)
    enter_votes: int = _f(
        3,
        "-",
        "of the last `votes` frames, this many occupied (or moving) set the verdict; all clear clear it",
        ge=1,
        le=100,
    )
    stale_s: float = _f(1.0, "s", "no frame judged for this long: the verdict is unknown", gt=0.0, le=60.0)
    hold_s: float = _f(
        10.0,
        "s",
        "an occupied pad: hold this long for it to clear, then divert or fly home with the parcel",
        ge=0.0,
        le=600.0,
    )

    @model_validator(mode="after")
    def _votes(self) -> DropZoneConfig:
        if self.enter_votes > self.votes:
            raise ValueError(f"enter_votes = {self.enter_votes} must be <= votes = {self.votes}")
        if self.window_m < 2 * self.grid_m:
            raise ValueError(f"window_m = {self.window_m} must be at least 2 x grid_m = {2 * self.grid_m}")
        return self


class MovingPadConfig(_Section):
    """A pad on a moving vehicle (a van, a boat; companion.estimation.moving_pad, docs/moving-pad.md):
    ``[landing.moving_pad]``. Off by default: the pad stands where it is configured (delivery 5.2)."""

    enabled: bool = _f(
        False,
        "-",
        "the pad may move: the EKF also estimates its horizontal velocity (14 states; needs landing.fusion "
        "and landing.use_camera)",
    )
    accel_sigma_m_s2: float = _f(
        0.3,
        "m/s^2",
        "the pad's acceleration as white noise (1-sigma per horizontal axis): the process noise of its velocity",
        gt=0.0,
        le=10.0,
    )
    initial_speed_sigma_m_s: float = _f(
        2.0, "m/s", "prior 1-sigma of each horizontal component of the pad's velocity (mean 0)", gt=0.0, le=20.0
    )
    max_speed_m_s: float = _f(
        3.5,
        "m/s",
        "the fastest pad the vehicle lands on: an estimated pad speed above it stops the descent and the "
        "release (docs/moving-pad.md, the stated limits)",
        gt=0.0,
        le=10.0,
    )


class LandingConfig(_Section):
    """Precision landing (delivery 4.2): fuse the camera and UWB with the GPS pose in the EKF."""

    fusion: bool = _f(True, "-", "use the EKF (GPS + camera + UWB); false = GPS-only baseline")
    use_camera: bool = _f(True, "-", "fuse pad observations from the downward camera")
    use_uwb: bool = _f(True, "-", "fuse UWB fixes from the anchors around the pad")
    vision_attitude: bool = _f(
        False,
        "-",
        "resolve the IPPE mirror pair of a lone marker with the autopilot's attitude (the pose whose "
        "pad normal agrees with it; neither agreeing: not fused)",
    )
    camera_rate_hz: float = _f(30.0, "Hz", "camera frame rate", ge=1.0, le=240.0)
    camera_latency_s: float = _f(0.05, "s", "exposure-to-delivery latency of a frame", ge=0.0, le=1.0)
    camera_time: Literal["configured", "driver", "measured"] = _f(
        "configured",
        "-",
        "a frame's exposure time for the fusion: its arrival minus camera_latency_s (configured); the driver's "
        "capture stamp (driver); its arrival minus the latency measured from the driver's stamps (measured); "
        "a frame without a driver stamp keeps camera_latency_s (docs/clock.md)",
    )
    camera_offset_body_m: tuple[float, float, float] = _f(
        (0.05, 0.0, 0.08), "m", "camera position in the body frame (FRD)"
    )
    uwb_rate_hz: float = _f(10.0, "Hz", "UWB ranging rate", ge=0.5, le=100.0)
    markers: Literal["both", "outer", "inner"] = _f("both", "-", "which of the nested pad's markers to use")
    camera_plugin: str = _f("opencv", "-", "companion.cameras plugin for the downward camera (companion fly)")
    camera_source: str = _f(
        "0", "-", "camera plugin source: V4L2 device index, video/image file, or GStreamer pipeline", min_length=1
    )
    camera_calibration: str = _f(
        "camera_rpi_v2.toml", "-", "camera calibration TOML (a path, or a file shipped in params/)", min_length=1
    )
    pad_file: str = _f("pad_delivery.toml", "-", "nested pad layout TOML (a path, or shipped in params/)", min_length=1)
    uwb_plugin: str = _f("dwm1001", "-", "companion.uwb plugin for the UWB tag (companion fly)")
    uwb_port: str = _f("/dev/ttyACM0", "-", "serial port of the UWB tag", min_length=1)
    uwb_anchors: str = _f(
        "uwb_anchors_pad.toml", "-", "UWB anchor layout TOML, pad frame (a path, or shipped in params/)", min_length=1
    )
    ekf_level_pad: bool = _f(
        False,
        "-",
        "the pad lies level (within a few tenths of a degree): the tilt the camera sees on it is the "
        "autopilot's roll / pitch error, taken out of the attitude the EKF fuses (a tilt error d puts "
        "the fused position h x tan(d) off at height h); leave off for a pad on a slope",
    )
    ekf_velocity_bias_tau_s: float = _f(
        0.0,
        "s",
        "> 0: the autopilot's velocity, the EKF's process input, is corrected by its bias, measured "
        "against mission.velocity_bias_source's position and low-passed with this time constant (as "
        "mission.velocity_bias_tau_s does for the setpoints; at most mission.velocity_bias_max_m_s). "
        "Without it a velocity estimate biased by b puts the fused position b x (camera latency + filter "
        "lag) off: PX4 v1.16 SIH, 0.3-0.5 m/s east near the ground, 4-8 cm. 0: the velocity as reported",
        ge=0.0,
        le=60.0,
    )
    controller: Literal["companion", "autopilot"] = _f(
        "companion",
        "-",
        "who flies the descent onto the pad: our fused EKF + velocity setpoints, or the autopilot's own "
        "precision landing (PX4 AUTO.PRECLAND, ArduPilot LAND with PLND) fed LANDING_TARGET",
    )
    landing_target_output: Literal["off", "local_ned", "body_angles"] = _f(
        "off",
        "-",
        "send LANDING_TARGET from our pad observations: local_ned (PX4: pad in its local frame), "
        "body_angles (ArduPilot PLND_TYPE=1: angles + distance), off",
    )
    policy: PadLockPolicyConfig = Field(default_factory=PadLockPolicyConfig)
    ekf: EkfConfig = Field(default_factory=EkfConfig)
    detector: DetectorConfig = Field(default_factory=DetectorConfig)
    drop_zone: DropZoneConfig = Field(default_factory=DropZoneConfig)
    multilateration: MultilaterationConfig = Field(default_factory=MultilaterationConfig)
    moving_pad: MovingPadConfig = Field(default_factory=MovingPadConfig)

    @model_validator(mode="before")
    @classmethod
    def _old_ekf_keys(cls, data: Any) -> Any:
        return read_moved_keys(data, LANDING_OLD_EKF_KEYS, "landing", "ekf")

    @model_validator(mode="after")
    def _moving_pad_needs_the_camera(self) -> LandingConfig:
        """A moving pad's velocity is observed only through pad-local data fused in the EKF, and the
        descent onto it needs the camera's sightings (UWB alone lags a moving pad by its fix rate)."""
        if self.moving_pad.enabled and not (self.fusion and self.use_camera):
            raise ValueError(
                f"moving_pad.enabled = true needs fusion = true and use_camera = true (got fusion = "
                f"{str(self.fusion).lower()}, use_camera = {str(self.use_camera).lower()}): the pad's "
                "velocity is estimated from the camera's sightings in the EKF"
            )
        return self


#: ``[landing]`` keys of older files -> their key in ``[landing.ekf]``
LANDING_OLD_EKF_KEYS = {
    "ekf_position_process_sigma_m_per_sqrt_s": "position_process_sigma_m_per_sqrt_s",
    "ekf_gate_reset_after_rejections": "gate_reset_after_rejections",
}


class SigningConfig(_Section):
    """MAVLink 2 message signing on the autopilot link (ArduPilot backend; mavsdk 4.1 has no
    signing API, see docs/signing.md). The key file is read when the backend is built."""

    enabled: bool = _f(False, "-", "sign every packet we send and check the vehicle's signatures")
    key_file: str | None = _f(
        None, "-", "file with the 32-byte secret: 64 hex digits, 32 raw bytes, or a passphrase (key_format)"
    )
    key_format: Literal["auto", "hex", "raw", "passphrase"] = _f(
        "auto",
        "-",
        "auto: 64 hex digits or 32 raw bytes; passphrase: one line, secret = SHA-256 of it "
        "(MAVProxy `signing setup PASSPHRASE`)",
    )
    link_id: int = _f(
        1, "-", "our link id in the signature (stream key with system/component; differ from the GCS)", ge=0, le=255
    )
    allow_unsigned: bool = _f(
        False,
        "-",
        "true: sign outgoing only and accept unsigned packets; false: drop unsigned or wrongly signed "
        "packets (RADIO_STATUS/RADIO excepted, as ArduPilot)",
    )
    timestamp_file: str | None = _f(
        None,
        "-",
        "file keeping our signing timestamp across restarts (saved every 30 s and on close; start 60 s "
        "past it, as ArduPilot): replay protection when the clock is not set; none: the clock only",
    )

    @model_validator(mode="after")
    def _key(self) -> SigningConfig:
        if self.enabled and not self.key_file:
            raise ValueError(
                "signing.enabled needs signing.key_file (64 hex digits, 32 raw bytes or a passphrase file; "
                "`companion signing keygen FILE` writes one)"
            )
        return self


class RemoteIdConfig(_Section):
    """Remote ID (docs/remote-id.md): what the companion gives the autopilot for its OpenDroneID
    transponder (OPEN_DRONE_ID_BASIC_ID, SELF_ID, SYSTEM, OPERATOR_ID, SYSTEM_UPDATE) and the arming
    gate on the transponder's OPEN_DRONE_ID_ARM_STATUS. Field encodings: MAVLink common.xml."""

    enabled: bool = _f(
        False,
        "-",
        "send the Remote ID messages at the rates below, and (ArduPilot) arm for a delivery only while the "
        "transponder's ARM_STATUS says good to arm (false: nothing sent, no gate)",
    )
    ua_type: int = _f(2, "-", "BASIC_ID ua_type, MAV_ODID_UA_TYPE (2: helicopter or multirotor; 0-15)", ge=0, le=15)
    id_type: int = _f(
        1,
        "-",
        "BASIC_ID id_type, MAV_ODID_ID_TYPE: 1 serial number (ANSI/CTA-2063-A), 2 CAA registration, "
        "3 UTM assigned UUID, 4 specific session id",
        ge=1,
        le=4,
    )
    uas_id: str = _f(
        "", "-", "BASIC_ID uas_id: the aircraft's id in id_type's format (ASCII, at most 20 characters)", max_length=20
    )
    operator_id: str = _f(
        "",
        "-",
        "OPERATOR_ID operator_id: the operator's registration (operator_id_type CAA; ASCII, at most 20 characters; "
        "empty: OPERATOR_ID not sent)",
        max_length=20,
    )
    self_id: str = _f(
        "",
        "-",
        "SELF_ID description, the flight's purpose as free text (description_type text; ASCII, at most 23 "
        "characters; empty: SELF_ID not sent)",
        max_length=23,
    )
    operator_location: Literal["home", "fixed"] = _f(
        "home",
        "-",
        "SYSTEM operator location: 'home' the autopilot's home position (operator_location_type takeoff), "
        "'fixed' operator_lat_deg / operator_lon_deg / operator_alt_m (operator_location_type fixed)",
    )
    operator_lat_deg: float = _f(0.0, "deg", "operator latitude (WGS-84) with operator_location 'fixed'", ge=-90, le=90)
    operator_lon_deg: float = _f(
        0.0, "deg", "operator longitude (WGS-84) with operator_location 'fixed'", ge=-180, le=180
    )
    operator_alt_m: float = _f(
        -1000.0,
        "m",
        "operator geodetic altitude (WGS-84) with operator_location 'fixed'; -1000: unknown (the spec's invalid)",
        ge=-1000.0,
        le=ALT_AMSL_MAX_M,
    )
    static_rate_hz: float = _f(
        0.5,
        "Hz",
        "rate of each of BASIC_ID, SELF_ID, OPERATOR_ID and SYSTEM (ArduPilot re-sends its copies to the "
        "transponder by itself; its pre-arm check wants a SYSTEM or SYSTEM_UPDATE less than 3 s old)",
        ge=0.2,
        le=5.0,
    )
    system_update_rate_hz: float = _f(
        1.0,
        "Hz",
        "rate of SYSTEM_UPDATE, the operator location and time (FAA: at least 1 Hz; PX4 reads no SYSTEM_UPDATE: "
        "there it is SYSTEM's rate); 0: not sent (PX4: SYSTEM at static_rate_hz)",
        ge=0.0,
        le=10.0,
    )
    arm_status_max_age_s: float = _f(
        3.0,
        "s",
        "an ARM_STATUS older than this counts as absent for the arming gate (ArduPilot's own check: 3 s)",
        gt=0.0,
        le=60.0,
    )

    @field_validator("uas_id", "operator_id", "self_id")
    @classmethod
    def _ascii(cls, v: str) -> str:
        if not v.isascii() or not v.isprintable():
            raise ValueError("must be printable ASCII (the MAVLink field is a char array)")
        return v

    @model_validator(mode="after")
    def _identified(self) -> RemoteIdConfig:
        if self.enabled and not self.uas_id:
            raise ValueError("remote_id.enabled needs remote_id.uas_id (BASIC_ID carries it)")
        if self.enabled and self.operator_location == "fixed" and self.operator_lat_deg == self.operator_lon_deg == 0:
            raise ValueError("remote_id.operator_location 'fixed' needs operator_lat_deg / operator_lon_deg")
        return self


class ExternalNavConfig(_Section):
    """External navigation (docs/external-nav.md): the fused pose streamed to the autopilot once the
    pad is locked (ArduPilot VISION_POSITION_ESTIMATE, VISO_TYPE = 1; PX4 ODOMETRY, EKF2_EV_CTRL = 1),
    and on ArduPilot the position source switched to it when GNSS is lost near the pad
    (MAV_CMD_SET_EKF_SOURCE_SET to ``source_set``, whose EK3_SRCn_POSXY = 6; PX4's EKF2 fuses it
    beside GNSS and goes on with it alone). Off by default: nothing sent, nothing switched."""

    enabled: bool = _f(
        False,
        "-",
        "stream the fused pose to the autopilot once the pad is locked and switch its position source to it "
        "when GNSS is lost (false: nothing sent, the autopilot's own GNSS failsafe acts)",
    )
    rate_hz: float = _f(
        20.0, "Hz", "VISION_POSITION_ESTIMATE rate (at most the guidance rate: one per tick)", ge=5.0, le=50.0
    )
    source_set: int = _f(
        2,
        "-",
        "the autopilot's EKF source set that navigates on the external pose (ArduPilot EK3_SRC<n>_*, 2 or 3; "
        "set 1 is GNSS)",
        ge=2,
        le=3,
    )
    gnss_min_fix_type: int = _f(3, "-", "GPS_RAW_INT fix type below this counts as GNSS lost (3: 3D)", ge=2, le=6)
    gnss_min_satellites: int = _f(
        5, "-", "fewer satellites than this count as GNSS lost (a collapsing constellation)", ge=0, le=30
    )
    gnss_lost_after_s: float = _f(
        0.5,
        "s",
        "GNSS must stay lost (or GPS_RAW_INT silent) this long before the source is switched",
        ge=0.0,
        le=10.0,
    )
    pad_data_max_age_s: float = _f(
        1.0,
        "s",
        "the pose is sent, and the source switched, only while the camera or UWB was fused within this: "
        "out of their range the pose is the autopilot's own velocity integrated, worth nothing to it",
        gt=0.0,
        le=5.0,
    )
    position_sigma_min_m: float = _f(
        0.05,
        "m",
        "floor of the position standard deviation sent with the pose (the EKF's own covariance above it)",
        gt=0.0,
        le=5.0,
    )


class CompanionConfig(_Section):
    vehicle_id: str = _f(
        "drone1",
        "-",
        "name of this vehicle (telemetry key space)",
        min_length=1,
        max_length=64,
        pattern=r"^[A-Za-z0-9_\-]+$",
    )
    autopilot: Literal["sim", "px4", "ardupilot"] = _f("sim", "-", "which autopilot backend to use")
    connection: str = _f("udpin://0.0.0.0:14540", "-", "MAVLink connection URL for px4/ardupilot")
    signing: SigningConfig = Field(default_factory=SigningConfig)
    mission: MissionConfig = Field(default_factory=MissionConfig)
    limits: LimitsConfig = Field(default_factory=LimitsConfig)
    runtime: RuntimeConfig = Field(default_factory=RuntimeConfig)
    sim: dict[str, Any] = Field(
        default_factory=dict,
        description="the embedded simulator's scenario ([sim], [sim.vehicle], [sim.winch]): taken as it is here "
        "and validated where the simulator loads it (companion_sitl.params.SimulatedConfig)",
        json_schema_extra={"unit": "-"},
    )
    telemetry: TelemetryConfig = Field(default_factory=TelemetryConfig)
    landing: LandingConfig = Field(default_factory=LandingConfig)
    payload: PayloadConfig = Field(default_factory=PayloadConfig)
    gcs: GcsConfig = Field(default_factory=GcsConfig)
    fence: FenceConfig = Field(default_factory=FenceConfig)
    go_no_go: GoNoGoConfig = Field(default_factory=GoNoGoConfig)
    winch: WinchConfig = Field(default_factory=WinchConfig)
    remote_id: RemoteIdConfig = Field(default_factory=RemoteIdConfig)
    external_nav: ExternalNavConfig = Field(default_factory=ExternalNavConfig)

    def _fenced_points(self) -> list[tuple[float, float, str]]:
        """(lat, lon, key) of every point the fence must hold at load: the pads given in lat/lon (a
        real home is only known in flight: the mission checks it when it plans). The simulator's
        config (companion_sitl.params.SimulatedConfig) puts its simulated home first."""
        return [
            (pad.lat_deg, pad.lon_deg, key)
            for key, pad in (("mission.pad", self.mission.pad), ("mission.alternate_pad", self.mission.alternate_pad))
            if pad is not None and pad.lat_deg is not None and pad.lon_deg is not None
        ]

    @model_validator(mode="after")
    def _fence_holds_home_and_pad(self) -> CompanionConfig:
        """The points of :meth:`_fenced_points` must lie inside the fence."""
        f = self.fence
        if not f.enabled:
            return self
        bad = [p for p in (f.problem_at(lat, lon, key) for lat, lon, key in self._fenced_points()) if p]
        if bad:
            raise ValueError("fence: " + "; ".join(bad))
        return self

    @model_validator(mode="after")
    def _winch_camera_sees(self) -> CompanionConfig:
        """The camera's look at the parcel needs a winch delivery and the camera fused."""
        if not self.winch.camera.enabled:
            return self
        if self.mission.delivery != "winch":
            raise ValueError(
                f"winch.camera.enabled = true with mission.delivery = {self.mission.delivery!r}: the camera looks "
                "at a parcel lowered on the winch; set delivery = 'winch' or winch.camera.enabled = false"
            )
        if not (self.landing.fusion and self.landing.use_camera):
            raise ValueError(
                "winch.camera.enabled = true needs landing.fusion = true and landing.use_camera = true: the "
                "parcel is placed from the camera's frames and the fused pose"
            )
        return self

    @model_validator(mode="after")
    def _alternate_pad_given(self) -> CompanionConfig:
        """A divert needs the alternate pad."""
        if self.mission.alternate_pad is None and self.landing.policy.fallback == "alternate":
            raise ValueError(
                "landing.policy.fallback = 'alternate' needs mission.alternate_pad (the pad to divert to); "
                "set [mission.alternate_pad] or fallback = 'home'"
            )
        return self

    @model_validator(mode="after")
    def _timeouts(self) -> CompanionConfig:
        if self.runtime.link_timeout_s >= self.mission.estimate_timeout_s:
            raise ValueError(
                f"runtime.link_timeout_s ({self.runtime.link_timeout_s}) must be < mission.estimate_timeout_s "
                f"({self.mission.estimate_timeout_s}): a lost link must be noticed before the estimate goes stale"
            )
        if self.mission.estimate_predict_max_s >= self.mission.estimate_timeout_s:
            raise ValueError(
                f"mission.estimate_predict_max_s ({self.mission.estimate_predict_max_s}) must be < "
                f"mission.estimate_timeout_s ({self.mission.estimate_timeout_s}): an estimate carried "
                "forward would otherwise never be seen to go stale"
            )
        if self.signing.enabled and self.autopilot == "px4":
            raise ValueError(
                "signing.enabled = true with autopilot = 'px4': the MAVSDK backend cannot sign (mavsdk 4.1's "
                "Python API and libcmavsdk have no MAVLink signing call); sign with autopilot = 'ardupilot'"
            )
        lc = self.landing
        if self.external_nav.enabled and not (lc.fusion and (lc.use_camera or lc.use_uwb)):
            raise ValueError(
                "external_nav.enabled = true needs landing.fusion = true with the camera or UWB: the pose sent to the "
                "autopilot is the fused one, which holds the pad only while they see it"
            )
        if self.external_nav.enabled and self.external_nav.rate_hz > self.runtime.guidance_rate_hz:
            raise ValueError(
                f"external_nav.rate_hz ({self.external_nav.rate_hz}) must be <= runtime.guidance_rate_hz "
                f"({self.runtime.guidance_rate_hz}): the pose is sent from the guidance tick, at most one per tick"
            )
        if lc.controller == "autopilot" and (lc.landing_target_output == "off" or not lc.use_camera):
            raise ValueError(
                f"landing.controller = 'autopilot' needs landing.landing_target_output 'local_ned' or 'body_angles' "
                f"(got {lc.landing_target_output!r}) and landing.use_camera = true (got {lc.use_camera}): "
                "the autopilot's precision landing only knows the pad from our LANDING_TARGET messages"
            )
        if lc.landing_target_output == "local_ned" and not lc.fusion:
            raise ValueError(
                "landing.landing_target_output = 'local_ned' needs landing.fusion = true: the pad's position in the "
                "autopilot's frame comes from the EKF's GPS-bias state"
            )
        if self.mission.delivery == "winch" and lc.controller == "autopilot":
            raise ValueError(
                "mission.delivery = 'winch' with landing.controller = 'autopilot': a winch delivery hovers on the "
                "companion's fused pad estimate and never hands a descent to the autopilot; use "
                "controller = 'companion'"
            )
        if self.mission.delivery == "winch" and self.autopilot == "px4":
            raise ValueError(
                "mission.delivery = 'winch' with autopilot = 'px4': PX4 v1.16 has no winch (its commander leaves "
                "DO_WINCH to other modules and none handles it: no COMMAND_ACK, no WINCH_STATUS; docs/winch.md); "
                "fly winch deliveries with autopilot = 'ardupilot'"
            )
        pol = lc.policy
        if pol.require_pad_lock and pol.search_radius_m > 0 and pol.search_height_m <= self.mission.final_descent_alt_m:
            raise ValueError(
                f"landing.policy.search_height_m ({pol.search_height_m}) must be above mission.final_descent_alt_m "
                f"({self.mission.final_descent_alt_m}), the approach height: the search climbs to see more ground"
            )
        if lc.drop_zone.enabled and not (lc.fusion and lc.use_camera):
            raise ValueError(
                f"landing.drop_zone.enabled = true needs landing.fusion = true and landing.use_camera = true (got "
                f"{lc.fusion} and {lc.use_camera}): the downward camera judges the drop zone, and the descent starts "
                "only once it has seen it clear"
            )
        return self


DEFAULT_PARAMS = "delivery_paper.toml"


def _describe_loc(loc: tuple[int | str, ...]) -> str:
    """A pydantic error location as a dotted key: ``anchors[0].position_m``."""
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc).removeprefix(".")


def _value_at(data: Any, loc: tuple[int | str, ...]) -> Any:
    for p in loc:
        try:
            data = data[p]
        except (KeyError, IndexError, TypeError):
            return None
    return data


def _format_errors(err: ValidationError, data: dict[str, Any]) -> list[str]:
    problems = []
    for e in err.errors():
        loc = _describe_loc(e["loc"])
        if e["type"] == "extra_forbidden":
            problems.append(
                f"{loc}: unknown key (value {e['input']!r}); allowed keys are listed by `companion params show`"
            )
            continue
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "finite_number":  # NaN or +-inf: the model config refuses them before any limit
            problems.append(f"{loc} = {e['input']!r}: not finite; expected a finite number")
            continue
        if e["type"] == "missing" and e["loc"] and isinstance(e["loc"][-1], int):  # a list one item short
            parent = _describe_loc(e["loc"][:-1])
            problems.append(f"{parent} = {_value_at(data, e['loc'][:-1])!r}: item [{e['loc'][-1]}] is missing")
        elif e["type"] == "missing":
            problems.append(f"{loc}: required key is missing")
        elif loc and isinstance(e["input"], dict):  # a rule between keys of a table names them itself
            problems.append(f"{loc}: {msg}")
        elif loc:
            problems.append(f"{loc} = {e['input']!r}: {msg}")
        else:
            problems.append(msg)
    return problems


_C = TypeVar("_C", bound=CompanionConfig)


def validate_config(schema: type[_C], data: dict[str, Any], source: str = "<dict>") -> _C:
    """``data`` validated by ``schema`` (:class:`CompanionConfig` or a subclass: the simulator's,
    companion_sitl.params.SimulatedConfig); :class:`ConfigError` naming ``source``."""
    try:
        return schema.model_validate(data)
    except ValidationError as err:
        raise ConfigError(source, _format_errors(err, data)) from None


def config_from_dict(data: dict[str, Any], source: str = "<dict>") -> CompanionConfig:
    return validate_config(CompanionConfig, data, source)


def _merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in override.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def read_toml(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(str(p), ["file not found"]) from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(str(p), [f"not valid TOML: {err}"]) from None
    except UnicodeDecodeError as err:
        raise ConfigError(str(p), [f"not UTF-8 text, as TOML must be: {err}"]) from None
    except ValueError as err:  # an integer of more digits than int() converts (sys.get_int_max_str_digits)
        raise ConfigError(str(p), [f"not valid TOML: a number TOML parsing refuses: {err}"]) from None
    except RecursionError:
        raise ConfigError(str(p), ["not valid TOML: arrays or tables nested too deeply"]) from None
    except OSError as err:
        raise ConfigError(str(p), [f"cannot read: {err.strerror}"]) from None


def shipped_params_path(name: str) -> Path:
    """A parameter set shipped in ``params/`` (installed as ``companion_params``)."""
    ref = resources.files("companion_params").joinpath(name)
    path = Path(str(ref))
    if not path.is_file():
        available = sorted(p.name for p in Path(str(resources.files("companion_params"))).glob("*.toml"))
        raise ConfigError(name, [f"no shipped parameter set of that name; shipped: {available}"])
    return path


def read_params(*paths: str | Path, overrides: dict[str, Any] | None = None) -> tuple[dict[str, Any], str]:
    """The tables of one or more TOML files merged (later ones override earlier ones, then
    ``overrides``), and the source to name in errors."""
    data: dict[str, Any] = {}
    sources = []
    for p in paths:
        data = _merge(data, read_toml(p))
        sources.append(str(p))
    if overrides:
        data = _merge(data, overrides)
        sources.append("<command line>")
    return data, " + ".join(sources) or "<defaults>"


def load_config(*paths: str | Path, overrides: dict[str, Any] | None = None) -> CompanionConfig:
    """Load and validate one or more TOML files (later ones override earlier ones)."""
    return config_from_dict(*read_params(*paths, overrides=overrides))


def _describe_field(key: str, value: Any, f: Any) -> str:
    extra = f.json_schema_extra if isinstance(f.json_schema_extra, dict) else {}
    unit = extra.get("unit", "")
    limits = []
    for m in f.metadata:
        for attr, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            v = getattr(m, attr, None)
            if v is not None:
                limits.append(f"{sym} {v}")
    lim = f" ({', '.join(limits)})" if limits else ""
    val = list(value) if isinstance(value, tuple) else value
    return f"{key} = {val!r} [{unit}]{lim}  {f.description or ''}"


def describe_parameters(cfg: BaseModel, prefix: str = "") -> list[str]:
    """One line per parameter: dotted key = value [unit] (limits) description."""
    lines = []
    for name, f in type(cfg).model_fields.items():
        value = getattr(cfg, name)
        key = f"{prefix}{name}"
        if isinstance(value, BaseModel):
            lines.append(f"[{key}]")
            lines.extend(describe_parameters(value, key + "."))
            continue
        if isinstance(value, tuple) and value and all(isinstance(v, BaseModel) for v in value):
            lines.append(_describe_field(key, f"{len(value)} tables", f))
            for i, item in enumerate(value):  # an array of tables, e.g. [[anchors]]
                lines.append(f"[{key}[{i}]]")
                lines.extend(describe_parameters(item, f"{key}[{i}]."))
            continue
        lines.append(_describe_field(key, value, f))
    return lines


def describe_schema(schema: type[BaseModel], prefix: str = "") -> list[str]:
    """:func:`describe_parameters` of a schema's defaults; a key without one shows as required."""
    lines = []
    for name, f in schema.model_fields.items():
        key = f"{prefix}{name}"
        ann = f.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            lines.append(f"[{key}]")
            if f.is_required():
                lines.extend(describe_schema(ann, key + "."))
            else:  # the table's default as built (a default_factory may set its own values)
                lines.extend(describe_parameters(f.get_default(call_default_factory=True), key + "."))
            continue
        value = "<required>" if f.is_required() else f.get_default(call_default_factory=True)
        lines.append(_describe_field(key, value, f))
    return lines
