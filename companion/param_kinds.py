"""The kinds of parameter file in ``params/`` and their schemas.

``params/`` holds six kinds of TOML file. Each kind is declared here (or, for the vehicle, in
:mod:`companion.config`) the same way: every key once, with its unit, limits and description
(``_f``). :func:`detect_kind` tells the kind of a file from its keys, :func:`validate` checks it
against its schema, and ``companion params check`` then also runs the kind's own loader for the
rules that tie keys together (a pad marker that does not fit, coplanar anchors).

| kind | file | read by |
|---|---|---|
| vehicle | ``delivery_paper.toml``, ``px4_sih_quad.toml``, ... | :func:`companion.config.load_config` |
| dart | ``dart_hover.toml`` | ``companion.dart.params``, the Dart simulator |
| camera | ``camera_rpi_v2.toml``, ``companion calibrate`` output | ``companion.vision.camera.load_camera`` |
| pad | ``pad_delivery.toml`` | ``companion.vision.pad.load_pad`` |
| anchors | ``uwb_anchors_pad.toml`` | ``companion.uwb.anchors.load_anchor_layout`` |
| zenoh | ``zenoh_*.toml`` | ``companion.telemetry.session.load_settings`` |

The Dart's tables are the Dart's own configs, taken as they are: ``[control]``
(``companion.dart.params.DartControlGains``), ``[mission]`` (``companion.dart.mission.DartMissionConfig``),
``[runtime]`` (``DartRuntimeConfig``, which adds the rules that need the Dart's modules; it *is*
the RC mixer's config, :class:`RcMixerTable`, and the attitude map, :class:`AttitudeMapTable`, whose
keys it inherits), ``[estimator]`` with ``[estimator.madgwick]`` and ``[estimator.complementary]``
(``companion.dart.estimators.DartEstimatorConfig`` adds the geometry;
``companion.estimation.madgwick.MadgwickConfig`` and ``...complementary.ComplementaryConfig`` are
:class:`MadgwickTable` and :class:`ComplementaryTable`), and ``[sim]`` (an attitude map too). For
the other tables the defaults here are the loaders' defaults and the limits are theirs, so
``params check`` accepts exactly what the application loads (tests/test_param_kinds.py holds keys
and defaults together).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, Field, ValidationError, model_validator

from companion.config import CompanionConfig, ConfigError, _f, _format_errors, _Section

FloatTriple = tuple[float, float, float]


def _s(default: Any, unit: str, description: str, **limits: Any) -> Any:
    """:func:`companion.config._f` for a scalar key, strict: the TOML type must already be right
    ('no' is not false, "3" is not 3); the loaders read these files without coercion either."""
    return _f(default, unit, description, strict=True, **limits)


IntQuad = tuple[int, int, int, int]
#: RC channels a Dart file may name (MAVLink RC_CHANNELS carries 18)
DART_RC_CHANNELS = 18

# ----------------------------------------------------------------------------------- camera
_DISTORTION = Literal["opencv", "dart"]


class CameraTable(_Section):
    """Pinhole camera with distortion (dart eqs 2-4); ``[camera]`` of a calibration file."""

    kind: _DISTORTION = _f(
        "opencv", "-", "distortion model: opencv (k1, k2, p1, p2, k3 in dist) or dart (one coefficient k_ud)"
    )
    width_px: int = _s(..., "px", "image width the calibration was made at", gt=0)
    height_px: int = _s(..., "px", "image height", gt=0)
    fx: float = _s(..., "px", "focal length along x", gt=0.0)
    fy: float = _s(..., "px", "focal length along y", gt=0.0)
    cx: float = _s(..., "px", "principal point x (inside the image)", ge=0.0)
    cy: float = _s(..., "px", "principal point y (inside the image)", ge=0.0)
    dist: tuple[float, float, float, float, float] = _f(
        (0.0, 0.0, 0.0, 0.0, 0.0), "-", "OpenCV distortion [k1, k2, p1, p2, k3] (all 0 with kind = dart)"
    )
    k_ud: float = _s(0.0, "-", "Dart single distortion coefficient (0 with kind = opencv)")

    @model_validator(mode="after")
    def _inside(self) -> CameraTable:
        if self.cx > self.width_px or self.cy > self.height_px:
            raise ValueError(
                f"principal point ({self.cx}, {self.cy}) must lie inside the image {self.width_px} x {self.height_px}"
            )
        return self


class CalibrationMeta(_Section):
    """Where a calibration came from (written by ``companion calibrate``)."""

    source: str | None = _s(None, "-", "what the values are (e.g. nominal datasheet values)")
    rms_px: float | None = _s(None, "px", "reprojection error (RMS) of the calibration", ge=0.0)
    n_images: int | None = _s(None, "-", "views used", ge=1)
    note: str | None = _s(None, "-", "free text")


class CameraFile(_Section):
    camera: CameraTable
    calibration: CalibrationMeta = Field(default_factory=CalibrationMeta)


# -------------------------------------------------------------------------------------- pad
class PadTable(_Section):
    """The nested ArUco pad (delivery 4.2.1): an inner marker centred in an outer one."""

    outer_id: int = _s(0, "-", "outer marker id in outer_dict", ge=0)
    outer_dict: str = _s("DICT_5X5_50", "-", "outer marker's cv2.aruco dictionary", pattern=r"^DICT_\w+$")
    outer_size_m: float = _s(0.8, "m", "outer marker side, black border included", gt=0.0)
    inner_id: int = _s(0, "-", "inner marker id in inner_dict", ge=0)
    inner_dict: str = _s(
        "DICT_4X4_50", "-", "inner marker's dictionary (another one than outer_dict)", pattern=r"^DICT_\w+$"
    )
    inner_size_m: float = _s(0.09, "m", "inner marker side, black border included", gt=0.0)
    pad_size_m: float = _s(1.0, "m", "side of the printed pad (white margin included)", gt=0.0)


class PadFile(_Section):
    pad: PadTable = Field(default_factory=PadTable)


# ---------------------------------------------------------------------------------- anchors
class AnchorEntry(_Section):
    id: str = _s(..., "-", "anchor id as the UWB tag reports it", pattern=r"^[0-9A-Za-z_-]{1,16}$")
    position_m: FloatTriple = _f(..., "m", "anchor position [x, y, z] in the anchor frame (z up)")

    @model_validator(mode="after")
    def _bounded(self) -> AnchorEntry:
        if any(not abs(c) <= 1000.0 for c in self.position_m):
            raise ValueError(f"position_m {list(self.position_m)}: coordinates must be finite, within +-1000 m")
        return self


class AnchorsFile(_Section):
    """UWB anchors around the pad (delivery 4.2.2)."""

    frame: str = _s("pad", "-", "name of the anchor frame (pad: origin at the pad centre, x east, y north, z up)")
    base_anchor: str | None = _s(None, "-", "TDoA base anchor (delivery eq 2, index 1); default the first anchor")
    max_range_m: float = _s(10.0, "m", "ranges beyond this are not used (DWM1001: 10 m)", gt=0.0, le=100.0)
    tag_side: Literal["above", "below"] = _f(
        "above", "-", "anchors at one height (coplanar): the side of their plane the tag flies on"
    )
    anchors: tuple[AnchorEntry, ...] = _f(
        ...,
        "-",
        "the [[anchors]] tables: at least 3 at one height (with tag_side), 4 at different heights",
        min_length=3,
    )

    @model_validator(mode="after")
    def _ids(self) -> AnchorsFile:
        ids = [a.id for a in self.anchors]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"anchor ids {dup} appear more than once")
        if self.base_anchor is not None and self.base_anchor not in ids:
            raise ValueError(f"base_anchor = {self.base_anchor!r}: must be one of the anchor ids {ids}")
        return self


# ------------------------------------------------------------------------------------ zenoh
class ZenohTable(_Section):
    """How the Zenoh session opens (companion.telemetry.session.ZenohSettings)."""

    mode: Literal["peer", "client", "router"] = _f("peer", "-", "Zenoh mode; the fleet's ground station is router")
    listen: tuple[str, ...] | None = _f(
        None, "-", "endpoints to listen on, e.g. tcp/0.0.0.0:7447 (absent: Zenoh's default, every interface)"
    )
    connect: tuple[str, ...] = _f((), "-", "endpoints to connect to")
    router_endpoint: str | None = _s(None, "-", "the fleet router to connect to (added to connect)")
    multicast_scouting: bool = _s(True, "-", "find peers by multicast (trusted LAN only)")
    gossip_scouting: bool = _s(True, "-", "learn peers from connected peers")
    scouting_delay_ms: int | None = _s(None, "ms", "how long opening waits for scouting replies", ge=0)
    connect_exit_on_failure: bool = _s(False, "-", "fail to open when no connect endpoint answers")
    connect_timeout_ms: int | None = _s(None, "ms", "connect attempt timeout", ge=0)
    user: str | None = _s(None, "-", "user presented to the router (with password)")
    password: str | None = _s(None, "-", "password presented to the router (with user)")
    auth_dictionary_file: str | None = _s(None, "-", "accepting side: file of user:password lines")
    overrides: dict[str, str] = _f({}, "-", "extra Zenoh json5 keys and values, applied last")
    max_message_bytes: int = _s(
        262144, "B", "largest message Zenoh reassembles; larger ones are dropped before Python", ge=65536, le=1 << 30
    )
    shared_memory: bool = _s(False, "-", "Zenoh's shared-memory transport (a buffer of any size, unfragmented)")
    max_sessions: int | None = _s(None, "-", "peers a session keeps (absent: Zenoh's 1000)", ge=1, le=10_000)
    accept_pending: int | None = _s(None, "-", "half-open connections (absent: Zenoh's 100)", ge=1, le=10_000)

    @model_validator(mode="after")
    def _endpoints(self) -> ZenohTable:
        eps = [*(self.listen or ()), *self.connect, *([self.router_endpoint] if self.router_endpoint else [])]
        protos = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream", "unixpipe", "serial", "vsock")
        bad = [e for e in eps if e.split("/", 1)[0] not in protos or "/" not in e or not e.split("/", 1)[1]]
        if bad:
            raise ValueError(f"endpoints {bad}: expected PROTOCOL/ADDRESS like 'tcp/127.0.0.1:7447'")
        if (self.user is None) != (self.password is None):
            raise ValueError("user and password go together")
        return self


class ZenohFile(_Section):
    zenoh: ZenohTable = Field(default_factory=ZenohTable)


# ------------------------------------------------------------------------------------- dart
class MadgwickTable(_Section):
    """The Madgwick attitude filter (dart eqs 12-13), ``[estimator.madgwick]``; taken as it is by
    ``companion.estimation.madgwick.MadgwickFilter`` (``MadgwickConfig``). The defaults give an
    accelerometer correction of gamma*mu/T = 0.1 quaternion units per second (Madgwick's default
    beta) at 200 Hz: mu "constant and large", gamma "quite small"."""

    mu: float = _s(0.1, "-", "dart eq 12 step size per sample at the nominal rate", ge=0.0)
    gamma: float = _s(0.005, "-", "dart eq 13 weight of the accelerometer quaternion", ge=0.0, le=1.0)
    nominal_rate_hz: float = _s(200.0, "Hz", "IMU rate mu is given at (dart sec. 4: 200 Hz)", gt=0.0)
    max_dt_s: float = _s(0.1, "s", "a longer IMU gap is integrated as max_dt_s (and counted)", gt=0.0)
    accel_min_m_s2: float = _s(
        1.0, "m/s^2", "|a| below: no gravity direction (free fall, zero read), no correction", ge=0.0
    )
    accel_max_m_s2: float = _s(40.0, "m/s^2", "|a| above: implausible, no correction (> accel_min_m_s2)", gt=0.0)

    @model_validator(mode="after")
    def _accel_band(self) -> MadgwickTable:
        if not self.accel_min_m_s2 < self.accel_max_m_s2:
            raise ValueError(f"accel_min_m_s2 ({self.accel_min_m_s2}) must be < accel_max_m_s2 ({self.accel_max_m_s2})")
        return self


class ComplementaryTable(_Section):
    """The complementary filter of FCF-CF (dart eq 14), ``[estimator.complementary]``; taken as
    it is by ``companion.estimation.complementary.ComplementaryFilter`` (``ComplementaryConfig``)."""

    lam: float = _s(0.9, "-", "dart eq 14 weight lambda (1: gyro only, 0: vision only)", ge=0.0, le=1.0)
    wrap: tuple[bool, bool, bool] = _f((True, True, True), "-", "which of the three components are angles to wrap")
    max_dt_s: float = _s(0.1, "s", "a longer prediction gap is integrated as max_dt_s (and counted)", gt=0.0)

    @staticmethod
    def from_time_constant(tau_s: float, period_s: float) -> ComplementaryTable:
        """lambda giving a first-order blend with time constant tau at the correction period:
        lambda = tau / (tau + T)."""
        if not (tau_s >= 0.0 and period_s > 0.0):
            raise ValueError("need tau_s >= 0 and period_s > 0")
        return ComplementaryTable(lam=tau_s / (tau_s + period_s))


class DartEstimatorTable(_Section):
    """The four position estimators' filter settings (dart eqs 12-21), ``[estimator]``; the
    geometry (camera mount, lens offset, marker heading) comes from ``[runtime]`` or ``[sim]``
    (``companion.dart.estimators.DartEstimatorConfig`` adds it)."""

    yaw_offset_rad: float = _s(0.0, "rad", "Madgwick yaw + offset = world yaw")
    yaw_align_tau_s: float | None = _s(
        None, "s", "vision yaw alignment time constant (not in the paper; absent: off)", ge=0.0
    )
    history_s: float = _s(0.5, "s", "attitude history kept for delayed camera observations", gt=0.0)
    max_attitude_age_s: float = _s(
        0.2, "s", "newest IMU sample older than this at the exposure: observation rejected", gt=0.0
    )
    max_rotation_error: float = _s(1e-3, "-", "|R R^T - I| of an observation above this: rejected", gt=0.0)
    madgwick: MadgwickTable = Field(default_factory=MadgwickTable)
    complementary: ComplementaryTable = Field(default_factory=ComplementaryTable)


class AttitudeMapTable(_Section):
    """Full stick deflection (500 us from neutral) in attitude units: the PX4 path's attitude
    setpoints (``companion.dart.mixer.AttitudeMapConfig``) and the simulated vehicle's response.
    Degrees in the file, radians to the code (``max_tilt_rad``, ``max_yaw_rate_rad_s``)."""

    max_tilt_deg: float = _s(35.0, "deg", "tilt at full stick deflection (500 us)", gt=0.0, lt=80.0)
    max_yaw_rate_deg_s: float = _s(150.0, "deg/s", "yaw rate at full stick deflection", gt=0.0)

    @property
    def max_tilt_rad(self) -> float:
        return math.radians(self.max_tilt_deg)

    @property
    def max_yaw_rate_rad_s(self) -> float:
        return math.radians(self.max_yaw_rate_deg_s)


class RcMixerTable(_Section):
    """The hybrid RC mixer (dart 3.2.2; ``companion.dart.mixer.RcMixer``, ``RcMixerConfig``):
    which channels the autopilot flies on, the pilot's engage switch, the stick range and the
    cyber-pilot's authority. Channels are 1-based (MAVLink chan1_raw = channel 1); stick tuples
    are (roll, pitch, throttle, yaw). The default map is ArduPilot's RCMAP (roll 1, pitch 2,
    throttle 3, yaw 4); with the FRD contribution signs no stick needs reversing on ArduPilot."""

    stick_channels: IntQuad = _f((1, 2, 3, 4), "-", "channels the autopilot flies on (roll, pitch, throttle, yaw)")
    stick_reversed: tuple[bool, bool, bool, bool] = _f((False, False, False, False), "-", "reversed sticks")
    switch_channel: int = _s(7, "-", "RC channel of the pilot's engage switch", ge=1, le=DART_RC_CHANNELS)
    engage_above_us: float = _s(
        1700.0, "us", "switch PWM above which the cyber-pilot is engaged (inside min_us..max_us)"
    )
    min_us: float = _s(1000.0, "us", "stick range: low end (pilot readings clamped to it)")
    max_us: float = _s(2000.0, "us", "stick range: high end")
    neutral_us: float = _s(1500.0, "us", "stick centre (min_us < neutral_us < max_us)")
    valid_min_us: float = _s(800.0, "us", "a pilot reading below this is invalid: disengage (<= min_us)")
    valid_max_us: float = _s(2200.0, "us", "a pilot reading above this is invalid: disengage (>= max_us)")
    max_contribution_us: tuple[float, float, float, float] = _f(
        (300.0, 300.0, 250.0, 300.0), "us", "largest autonomous contribution per stick (each >= 0)"
    )

    @model_validator(mode="after")
    def _mixer_rules(self) -> RcMixerTable:
        if any(v < 0.0 for v in self.max_contribution_us):
            raise ValueError(f"max_contribution_us = {list(self.max_contribution_us)}: must be >= 0")
        chans = (*self.stick_channels, self.switch_channel)
        if any(not 1 <= c <= DART_RC_CHANNELS for c in chans):
            raise ValueError(f"channels must be in 1..{DART_RC_CHANNELS}: {chans}")
        if len(set(chans)) != len(chans):
            raise ValueError(
                f"stick_channels = {self.stick_channels!r} and switch_channel = {self.switch_channel}: must all differ"
            )
        if not self.valid_min_us <= self.min_us < self.neutral_us < self.max_us <= self.valid_max_us:
            raise ValueError(
                f"valid_min_us <= min_us < neutral_us < max_us <= valid_max_us: got {self.valid_min_us}, "
                f"{self.min_us}, {self.neutral_us}, {self.max_us}, {self.valid_max_us}"
            )
        if not self.min_us < self.engage_above_us < self.max_us:
            raise ValueError(
                f"engage_above_us = {self.engage_above_us}: must lie inside min_us..max_us "
                f"({self.min_us}..{self.max_us})"
            )
        return self

    @property
    def channels(self) -> IntQuad:
        return self.stick_channels

    @property
    def signs(self) -> tuple[float, float, float, float]:
        return tuple(-1.0 if r else 1.0 for r in self.stick_reversed)  # type: ignore[return-value]


class DartSimTable(AttitudeMapTable):
    """The Dart simulator (companion_sitl.dart_sim.DartSimConfig): vehicle, disturbances, IMU,
    camera and gimbal, the wall marker."""

    physics_hz: float = _s(1000.0, "Hz", "integration rate (the IMU runs at 200 Hz)", ge=400.0)
    drag_per_s: float = _s(0.3, "1/s", "linear drag per unit mass", ge=0.0)
    attitude_tau_s: float = _s(0.08, "s", "roll/pitch first-order response to the setpoint", gt=0.0)
    yaw_rate_tau_s: float = _s(0.1, "s", "yaw-rate first-order response", gt=0.0)
    throttle_mode: Literal["climb_rate", "thrust"] = _f(
        "climb_rate", "-", "climb_rate (ALT_HOLD: stick -> climb rate) or thrust (STABILIZE)"
    )
    max_climb_m_s: float = _s(2.5, "m/s", "climb rate at full stick in climb_rate mode", gt=0.0)
    climb_gain_per_s: float = _s(4.0, "1/s", "vertical speed loop gain in climb_rate mode", gt=0.0)
    hover_throttle: float = _s(0.5, "-", "thrust fraction that hovers in thrust mode", gt=0.0, lt=1.0)
    wind_ned_m_s: FloatTriple = _f((0.3, 0.2, 0.0), "m/s", "mean wind (N, E, D)")
    gust_std_m_s: float = _s(0.1, "m/s", "horizontal gust std (vertical: half)", ge=0.0)
    gust_tau_s: float = _s(2.0, "s", "gust correlation time", gt=0.0)
    attitude_disturbance_deg: float = _s(0.2, "deg", "std of the inner loop's residual attitude error", ge=0.0)
    attitude_disturbance_tau_s: float = _s(0.3, "s", "correlation time of that error", gt=0.0)
    gyro_noise_rad_s: float = _s(0.0012, "rad/s", "gyro white noise per sample", ge=0.0)
    gyro_bias_rad_s: float = _s(0.0005, "rad/s", "gyro bias left after calibration (std per axis)", ge=0.0)
    accel_noise_m_s2: float = _s(0.01, "m/s^2", "accelerometer white noise per sample", ge=0.0)
    accel_bias_m_s2: float = _s(0.03, "m/s^2", "accelerometer bias (std per axis)", ge=0.0)
    accel_vibration_m_s2: float = _s(2.0, "m/s^2", "motor vibration amplitude per axis", ge=0.0)
    gyro_vibration_rad_s: float = _s(0.1, "rad/s", "motor vibration amplitude per axis", ge=0.0)
    vibration_hz: float = _s(117.0, "Hz", "vibration frequency (motor rotation)", gt=0.0)
    camera_file: str = _s("", "-", "camera calibration TOML (empty: the shipped nominal Raspberry Pi camera v2)")
    camera_scale: float = _s(1.0, "-", "image scale (1.0: 640x480, 0.5: 320x240)", gt=0.0)
    camera_latency_s: float = _s(0.06, "s", "exposure to observation available to the estimator", ge=0.0)
    exposure_s: float = _s(0.008, "s", "exposure time (motion blur)", gt=0.0)
    image_noise_std: float = _s(2.0, "grey", "image noise std in grey levels", ge=0.0)
    lens_offset_m: FloatTriple = _f((0.08, 0.0, 0.03), "m", "lens position from the centre of thrust, body FRD")
    gimbal_tau_s: float = _s(0.01, "s", "gimbal response time constant", gt=0.0)
    gimbal_coupling: float = _s(0.2, "-", "fraction of the body's rotation reaching a gimbal axis", ge=0.0, le=1.0)
    gimbal_noise_deg: float = _s(0.02, "deg", "gimbal angle noise (Tarot: 0.02 deg, dart 2.4)", ge=0.0)
    outer_size_m: float = _s(0.5, "m", "wall marker: outer marker side", gt=0.0)
    inner_size_m: float = _s(0.09, "m", "wall marker: inner marker side", gt=0.0)
    pad_size_m: float = _s(0.6, "m", "wall marker: printed pad side", gt=0.0)
    wall_size_m: float = _s(12.0, "m", "side of the rendered wall", gt=0.0)
    wall_clutter: int = _s(40, "-", "clutter shapes drawn on the wall", ge=0)
    start_offset_m: FloatTriple = _f((0.05, -0.05, 0.1), "m", "start position from the setpoint, marker frame")


class DartControlTable(_Section):
    """Gains of the four decoupled PIDs (dart 3.2.2), in RC microseconds: ``[control]``, taken as
    it is by the Dart (``companion.dart.params.DartControlGains``, ``controller_config``).
    "Horizontal" is C_x and C_z (roll and pitch), "vertical" C_y (climb). dart 3.2.2: the PIDs
    were tuned on numerical simulations of a simplified model; these are tuned on the simulator
    (companion_sitl.dart_sim), identical for every estimator."""

    horizontal_kp: float = _s(400.0, "us/m", "roll/pitch P", ge=0.0)
    horizontal_ki: float = _s(120.0, "us/(m s)", "roll/pitch I", ge=0.0)
    horizontal_kd: float = _s(250.0, "us s/m", "roll/pitch D", ge=0.0)
    horizontal_limit_us: float = _s(200.0, "us", "roll/pitch output limit", gt=0.0)
    horizontal_i_limit_us: float = _s(100.0, "us", "roll/pitch integrator limit", ge=0.0)
    vertical_kp: float = _s(150.0, "us/m", "climb P", ge=0.0)
    vertical_ki: float = _s(40.0, "us/(m s)", "climb I", ge=0.0)
    vertical_kd: float = _s(60.0, "us s/m", "climb D", ge=0.0)
    vertical_limit_us: float = _s(200.0, "us", "climb output limit", gt=0.0)
    vertical_i_limit_us: float = _s(150.0, "us", "climb integrator limit", ge=0.0)
    d_filter_tau_s: float = _s(0.1, "s", "derivative low-pass time constant", ge=0.0)
    yaw_kp: float = _s(200.0, "us/rad", "yaw P", ge=0.0)
    yaw_limit_us: float = _s(150.0, "us", "yaw output limit", gt=0.0)
    max_dt_s: float = _s(0.5, "s", "a longer gap between control steps: the derivative restarts", gt=0.0)
    max_estimate_age_s: float = _s(0.3, "s", "an older position estimate gives no contribution", gt=0.0)


class DartMissionTable(_Section):
    """Hover points in the marker frame, the approach's peak speed, the hover time (dart 5):
    ``[mission]``, taken as it is by the Dart mission (``companion.dart.mission.DartMissionConfig``)."""

    start_distance_m: float = _s(4.0, "m", "hover distance in front of the marker (dart 5.2)", gt=0.0)
    end_distance_m: float = _s(1.5, "m", "distance the approach ends at (< start_distance_m)", gt=0.0)
    x_m: float = _s(0.0, "m", "lateral offset of the path (marker x, right)")
    y_m: float = _s(0.0, "m", "height of the path relative to the marker centre (marker y, up)")
    yaw_rad: float = _s(0.0, "rad", "heading setpoint relative to facing the marker")
    max_speed_m_s: float = _s(0.1, "m/s", "peak of the triangular approach profile (dart 5.3)", gt=0.0)
    hover_s: float = _s(25.0, "s", "hover before the approach", ge=0.0)
    approach: bool = _s(True, "-", "false: hover at the start point only")

    @model_validator(mode="after")
    def _towards(self) -> DartMissionTable:
        if self.end_distance_m >= self.start_distance_m:
            raise ValueError(
                f"end_distance_m ({self.end_distance_m}) must be < start_distance_m ({self.start_distance_m}): "
                "the approach moves towards the marker"
            )
        return self

    @property
    def path_length_m(self) -> float:
        return self.start_distance_m - self.end_distance_m

    @property
    def approach_duration_s(self) -> float:
        """T = 2 D / v of the triangular profile."""
        return 2.0 * self.path_length_m / self.max_speed_m_s


class DartRuntimeTable(RcMixerTable, AttitudeMapTable):
    """The Dart runtime on a real autopilot (companion.dart.params.DartRuntimeConfig). Channels
    are 1-based; stick tuples are (roll, pitch, throttle, yaw)."""

    estimator: str = _s(
        "SCF-MF-3DOF", "-", "position estimator (dart eqs 14-21): FCF-CF, FCF-MF, SCF-MF-2DOF or SCF-MF-3DOF"
    )
    imu_hz: float = _s(200.0, "Hz", "IMU and estimator rate", gt=0.0)
    vision_hz: float = _s(30.0, "Hz", "camera poll rate", gt=0.0)
    control_hz: float = _s(22.0, "Hz", "control rate (dart 4: 22 Hz)", gt=0.0)
    command_hz: float = _s(44.0, "Hz", "command rate (>= control_hz)", gt=0.0)
    log_hz: float = _s(20.0, "Hz", "log rate", gt=0.0)
    pilot_channels: IntQuad = _f((9, 10, 11, 12), "-", "channels the pilot's sticks are read on (mirrored)")
    contribution_timeout_s: float = _s(0.15, "s", "an older control output is not mixed", gt=0.0)
    rc_timeout_s: float = _s(0.3, "s", "no RC_CHANNELS for this long: disengage and release", gt=0.0)
    release_repeat: int = _s(5, "-", "release messages sent after a disengagement", ge=1)
    marker_heading_deg: float = _s(0.0, "deg", "heading (NED) of a drone facing the marker")
    align_yaw_to_autopilot: bool = _s(True, "-", "Madgwick yaw := autopilot heading at each engagement")
    lens_offset_m: FloatTriple = _f((0.08, 0.0, 0.03), "m", "lens from the centre of thrust, body FRD")
    camera_plugin: str = _s("opencv", "-", "companion.cameras plugin")
    camera_source: str = _s("0", "-", "camera plugin source (device index, file, GStreamer pipeline)")
    camera_latency_s: float = _s(0.0, "s", "subtracted from the capture time stamp", ge=0.0)
    camera_file: str = _s("", "-", "calibration TOML (empty: the shipped Raspberry Pi camera v2)")
    camera_scale: float = _s(1.0, "-", "image scale of the calibration", gt=0.0)
    outer_size_m: float = _s(0.5, "m", "wall marker: outer marker side", gt=0.0)
    inner_size_m: float = _s(0.09, "m", "wall marker: inner marker side", gt=0.0)
    pad_size_m: float = _s(0.6, "m", "wall marker: printed pad side", gt=0.0)
    opencv_threads: int = _s(
        1, "-", "threads OpenCV's parallel loops may use (1: the vision thread only; -1: one per CPU)", ge=-1, le=64
    )
    realtime_priority: int = _s(
        0,
        "-",
        "Linux SCHED_RR priority of the shell's threads, the vision thread one lower (docs/flying.md); 0: normal",
        ge=0,
        le=98,
    )

    @model_validator(mode="after")
    def _channels_and_rates(self) -> DartRuntimeTable:
        chans = (*self.pilot_channels,)
        if any(not 1 <= c <= DART_RC_CHANNELS for c in chans):
            raise ValueError(f"channels must be in 1..{DART_RC_CHANNELS}: {chans}")
        if len(set(self.pilot_channels)) != 4 or self.switch_channel in self.pilot_channels:
            raise ValueError(
                f"pilot_channels = {self.pilot_channels!r}: four different channels, not the switch channel"
            )
        if set(self.pilot_channels) & set(self.stick_channels) and self.pilot_channels != self.stick_channels:
            raise ValueError(
                f"pilot_channels = {self.pilot_channels!r}: either the stick_channels themselves or channels "
                f"apart from them (stick_channels = {self.stick_channels!r})"
            )
        if self.command_hz < self.control_hz:
            raise ValueError(f"command_hz = {self.command_hz!r}: must be >= control_hz = {self.control_hz!r}")
        return self

    @property
    def estimator_name(self) -> str:
        return self.estimator.strip().upper().replace("_", "-")

    @property
    def pilot_mirrored(self) -> bool:
        """The pilot's sticks are read on other channels than the ones the autopilot flies on."""
        return self.pilot_channels != self.stick_channels


class DartFile(_Section):
    sim: DartSimTable = Field(default_factory=DartSimTable)
    control: DartControlTable = Field(default_factory=DartControlTable)
    mission: DartMissionTable = Field(default_factory=DartMissionTable)
    runtime: DartRuntimeTable = Field(default_factory=DartRuntimeTable)
    estimator: DartEstimatorTable = Field(default_factory=DartEstimatorTable)


# ------------------------------------------------------------------------------------ kinds
@dataclass(frozen=True)
class ParamKind:
    name: str
    schema: type[BaseModel]
    what: str


KINDS: dict[str, ParamKind] = {
    k.name: k
    for k in (
        ParamKind("vehicle", CompanionConfig, "delivery vehicle and mission (companion demo/fly/campaign --params)"),
        ParamKind("dart", DartFile, "Dart cyber-pilot: sim, PID gains, mission, runtime, estimators (companion dart)"),
        ParamKind("camera", CameraFile, "camera calibration (landing.camera_calibration, companion calibrate)"),
        ParamKind("pad", PadFile, "nested ArUco landing pad (landing.pad_file, companion pad)"),
        ParamKind("anchors", AnchorsFile, "UWB anchor layout around the pad (landing.uwb_anchors)"),
        ParamKind("zenoh", ZenohFile, "Zenoh session (telemetry.zenoh_config, companion ground --zenoh-config)"),
    )
}


def _keys(schema: type[BaseModel], prefix: str = "") -> set[str]:
    """Every dotted key a schema declares (tables too)."""
    out: set[str] = set()
    for name, f in schema.model_fields.items():
        key = prefix + name
        out.add(key)
        ann = f.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            out |= _keys(ann, key + ".")
    return out


def _data_keys(data: Mapping[str, Any], prefix: str = "") -> set[str]:
    out: set[str] = set()
    for k, v in data.items():
        out.add(prefix + k)
        if isinstance(v, Mapping):
            out |= _data_keys(v, f"{prefix}{k}.")
    return out


_SCHEMA_KEYS: dict[type[BaseModel], frozenset[str]] = {}


def _schema_keys(schema: type[BaseModel]) -> frozenset[str]:
    if schema not in _SCHEMA_KEYS:
        _SCHEMA_KEYS[schema] = frozenset(_keys(schema))
    return _SCHEMA_KEYS[schema]


def detect_kind(data: Mapping[str, Any], kinds: Mapping[str, ParamKind] = KINDS) -> str:
    """The kind whose schema declares most of the file's dotted keys (ties: the order of
    ``kinds``, vehicle first). A file with a typo or a bad value still matches its kind.
    ``kinds``: :data:`KINDS`, or the command line's, whose vehicle schema validates ``[sim]`` too."""
    keys = _data_keys(data)
    scores = {name: len(keys & _schema_keys(k.schema)) for name, k in kinds.items()}
    return max(kinds, key=lambda name: scores[name])  # max keeps the first of equal scores


def validate(data: Mapping[str, Any], kind: str, source: str, kinds: Mapping[str, ParamKind] = KINDS) -> BaseModel:
    """``data`` checked against the schema of ``kind`` (in ``kinds``, as :func:`detect_kind`);
    :class:`ConfigError` naming ``source`` and, per problem, the dotted key, the value and what is expected."""
    if kind not in kinds:
        raise ConfigError(source, [f"kind {kind!r}: expected one of {', '.join(kinds)}"])
    try:
        return kinds[kind].schema.model_validate(dict(data))
    except ValidationError as err:
        raise ConfigError(source, _format_errors(err, dict(data))) from None


__all__ = ["KINDS", "ParamKind", "detect_kind", "validate"]
