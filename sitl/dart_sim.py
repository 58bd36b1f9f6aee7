"""Lock-step simulation of the Dart experiment (dart secs. 2-5): a quadrotor on an attitude-
setpoint path, its IMU, a forward camera (fixed, 2-DOF or 3-DOF gimbal) rendering real images of a
wall marker, the detector on those pixels, one Dart estimator, the PID controller, the hybrid RC
mixer and a simulated pilot.

Import as ``from companion_sitl.dart_sim import DartSim``. Deterministic for a given seed; time
is simulated (physics at ``physics_hz``), nothing reads a clock.

Frames: world NED with the marker centre at the origin on a vertical wall facing south
(dart.estimators.wall_marker(0): marker x = east, y = up, z = south, towards the
drone); body FRD; camera OpenCV. A drone heading north 4 m south of the wall is at marker
z = 4 (the Dart estimators' output frame).

Vehicle (the low-level flight controller, dart sec. 3.1, ArduPilot STABILIZE / ALT_HOLD-like):
RC sticks -> roll / pitch angle setpoints (full stick = ``max_tilt_deg``, via
companion.dart.mixer.attitude_setpoint), yaw stick -> yaw rate, throttle -> climb rate
(``throttle_mode = "climb_rate"``, ALT_HOLD: mid stick holds the altitude, the vertical speed
loop has gain ``climb_gain_per_s``) or -> thrust (``"thrust"``, STABILIZE: mid stick = hover
thrust). Roll and pitch follow their setpoints with a first-order response (``attitude_tau_s``),
the yaw rate likewise; the inner loop's imperfect rejection of turbulent torques is a
Gauss-Markov attitude disturbance added on top. Translation: thrust along body -z, gravity,
linear drag against the air velocity (wind = mean + Gauss-Markov gusts).

IMU (200 Hz, dart sec. 4): gyro = body rates + bias + white noise + vibration; accelerometer =
specific force + bias + white noise + vibration (the frame's motor vibration, ``vibration_hz``,
sampled at 200 Hz without anti-aliasing, as a cheap I2C IMU does). The body also shakes in angle
at the vibration frequency (amplitude = gyro vibration / (2 pi f)), which the fixed camera sees.

Camera (~30 Hz, capture latency): SimulatedCamera renders the wall marker (a nested PadLayout
placed on the wall; the wall carries the simulated clutter texture); motion blur along the image
motion of the exposure (camera angular rate x exposure time), then exposure noise. Mounts:
- none (FCF-*): camera rigid on the body;
- 2-DOF gimbal (SCF-MF-2DOF): camera roll and pitch held level, yaw with the body;
- 3-DOF gimbal (SCF-MF-3DOF): camera attitude held, heading ``gimbal_yaw``.
A gimbal axis is dragged by the body's motion (``gimbal_coupling``) and restored by its motor
with time constant ``gimbal_tau_s``, plus ``gimbal_noise_deg`` (the paper's 0.02 deg precision).

Tasks (dart sec. 4, DartTaskRates): estimator IMU update 200 Hz; vision on every frame, the
observation (timestamped at exposure) handed to the estimator when the frame becomes available;
control (mission + DartController) 22 Hz; commands through RcMixer 44 Hz. When the mixer is
disengaged the override is released and the flight controller reads the pilot's sticks directly.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import model_validator

from companion.dart.control import DartCommand, DartController, DartControllerConfig, DartSetpoint
from companion.dart.estimators import (
    CameraMarkerObservation,
    DartEstimator,
    DartEstimatorConfig,
    DartPositionEstimate,
    DartTaskRates,
    GimbalKind,
    camera_mount,
    make_estimator,
    wall_marker,
)
from companion.dart.mission import (
    DartMission,
    DartMissionConfig,
    load_mission_config,
    model_from_table,
    read_toml,
)
from companion.dart.mixer import AttitudeMapConfig, RcMixer, RcMixerConfig, attitude_setpoint
from companion.dart.params import DartControlGains, DartRuntimeConfig, check_tables, controller_config
from companion.geometry import Transform, euler_to_rotmat
from companion.param_kinds import DartEstimatorTable, DartSimTable
from companion.vision.camera import CameraModel, load_default_camera
from companion.vision.detector import MarkerObservation, PadDetector, marker_normal_in_camera, rotation_angle
from companion.vision.pad import PadLayout

from .camera import SimCameraConfig, SimulatedCamera

log = logging.getLogger(__name__)

G = 9.80665
FloatArray = NDArray[np.float64]

#: The gimbal each estimator is flown with in the paper (dart secs. 3.2.4, 5).
ESTIMATOR_GIMBAL: dict[str, GimbalKind] = {
    "FCF-CF": GimbalKind.NONE,
    "FCF-MF": GimbalKind.NONE,
    "SCF-MF-2DOF": GimbalKind.TWO_DOF,
    "SCF-MF-3DOF": GimbalKind.THREE_DOF,
}

NEUTRAL_US = 1500.0
DIST_SMOOTH_S = 0.05  # smoothing lag of the attitude disturbance
SWITCH_ON_US = 2000.0
SWITCH_OFF_US = 1000.0


class DartSimConfig(DartSimTable):
    """Every physical and sensor parameter of the Dart simulation: ``[sim]`` of a Dart file, its
    keys declared once (unit, limits, description) in companion.param_kinds.DartSimTable; here
    the one rule that needs the vision code: the wall marker's sizes make a pad."""

    @model_validator(mode="after")
    def _marker_fits(self) -> DartSimConfig:
        self.layout  # noqa: B018 -- PadLayout checks the sizes
        return self

    @property
    def layout(self) -> PadLayout:
        return PadLayout(outer_size_m=self.outer_size_m, inner_size_m=self.inner_size_m, pad_size_m=self.pad_size_m)


@dataclass(frozen=True, slots=True)
class DartParams:
    """A Dart parameter file: the simulation, the controller gains and the mission."""

    sim: DartSimConfig = field(default_factory=DartSimConfig)
    control: DartControlGains = field(default_factory=DartControlGains)
    mission: DartMissionConfig = field(default_factory=DartMissionConfig)
    runtime: DartRuntimeConfig = field(default_factory=DartRuntimeConfig)  # the companion over MAVLink
    estimator: DartEstimatorTable = field(default_factory=DartEstimatorTable)  # the estimators' filters


def load_dart_params(path: str | Path) -> DartParams:
    """params/dart_hover.toml: tables [sim], [control], [mission], [runtime], [estimator]; errors name file,
    key, value and rule."""
    doc = read_toml(path)
    check_tables(doc, path)
    return DartParams(
        sim=model_from_table(DartSimConfig, doc.get("sim", {}), path, "sim"),
        control=model_from_table(DartControlGains, doc.get("control", {}), path, "control"),
        mission=load_mission_config(path),
        runtime=model_from_table(DartRuntimeConfig, doc.get("runtime", {}), path, "runtime"),
        estimator=model_from_table(DartEstimatorTable, doc.get("estimator", {}), path, "estimator"),
    )


def shipped_dart_params() -> Path:
    """The shipped params/dart_hover.toml (installed as ``companion_params``)."""
    return Path(str(resources.files("companion_params").joinpath("dart_hover.toml")))


def attitude_response(
    c: DartSimConfig,
    dt: float,
    att_c: tuple[float, float, float],
    sp: tuple[float, float, float],
    dist: list[float],
    dist_gm: list[float],
    noise: Callable[[], float],
) -> tuple[tuple[float, float, float], list[float], float]:
    """The flight controller's attitude loop and the airframe's disturbance, one step.

    ``att_c`` = (commanded roll, pitch, current yaw rate), ``sp`` = (roll, pitch, yaw-rate
    setpoints). Roll and pitch follow their setpoints first-order (``attitude_tau_s``), the yaw
    rate lags its setpoint (``yaw_rate_tau_s``). The disturbance is a Gauss-Markov process
    (``dist_gm``) smoothed by a first-order lag (``DIST_SMOOTH_S``) into ``dist`` so that it has a
    finite rate (the body's rotation is twice integrated from the disturbing torque; a white-driven
    angle would give the gyro an infinite rate); both lists are updated in place, drawing three
    ``noise()`` samples. Returns the commanded Euler rates (roll, pitch, yaw), the disturbance's
    Euler rates and the next yaw rate; the caller integrates the commanded angles.
    """
    roll_c, pitch_c, yaw_rate = att_c
    ka = 1.0 / c.attitude_tau_s
    r = (ka * (sp[0] - roll_c), ka * (sp[1] - pitch_c), yaw_rate)
    yaw_rate_next = yaw_rate + dt / c.yaw_rate_tau_s * (sp[2] - yaw_rate)
    phi_d = math.exp(-dt / c.attitude_disturbance_tau_s)
    sd = math.radians(c.attitude_disturbance_deg) * math.sqrt(1.0 - phi_d * phi_d)
    d_rate = [(dist_gm[i] - dist[i]) / DIST_SMOOTH_S for i in range(3)]
    for i in range(3):
        dist[i] += d_rate[i] * dt
        dist_gm[i] = phi_d * dist_gm[i] + sd * noise()
    return r, d_rate, yaw_rate_next


def thrust_per_mass(c: DartSimConfig, throttle_mode: str, thrust: float, vd_m_s: float, tilt_cos: float) -> float:
    """The flight controller's collective thrust per mass (m/s^2) for the throttle stick
    ``thrust`` (0..1): ``"climb_rate"`` (ALT_HOLD: mid stick holds the altitude, the vertical
    speed loop tracks the stick's climb rate, tilt-compensated) or ``"thrust"`` (STABILIZE: mid
    stick = ``hover_throttle`` of thrust). ``vd_m_s``: NED down speed; ``tilt_cos``:
    cos(roll) cos(pitch). Shared by DartSim and the MAVLink stick vehicle (dart_link)."""
    if throttle_mode == "climb_rate":
        vd_sp = -(2.0 * thrust - 1.0) * c.max_climb_m_s
        a_cmd = c.climb_gain_per_s * (vd_sp - vd_m_s)  # NED down acceleration wanted
        f_t = (G - a_cmd) / max(0.3, tilt_cos)
    else:
        f_t = G * thrust / c.hover_throttle
    return max(0.0, min(2.5 * G, f_t))


# ------------------------------------------------------------------------------ pilot
PilotFn = Callable[[float], Sequence[float]]


def pilot_channels(
    roll_us: float = NEUTRAL_US,
    pitch_us: float = NEUTRAL_US,
    throttle_us: float = NEUTRAL_US,
    yaw_us: float = NEUTRAL_US,
    switch_us: float = SWITCH_ON_US,
) -> tuple[float, ...]:
    """Eight RC channels (ArduPilot RCMAP, switch on channel 7) of the pilot's transmitter."""
    return (roll_us, pitch_us, throttle_us, yaw_us, NEUTRAL_US, NEUTRAL_US, switch_us, NEUTRAL_US)


def neutral_pilot(time_s: float) -> Sequence[float]:
    """The pilot's sticks at neutral, autonomous (hybrid) mode switched on."""
    return pilot_channels()


# ------------------------------------------------------------------------------ records
@dataclass(frozen=True, slots=True)
class DartSample:
    """One control step: the estimate used, the truth (centre of thrust, marker frame) and the
    setpoint; NaN estimate when none was usable."""

    time_s: float
    engaged: bool
    est: tuple[float, float, float]
    truth: tuple[float, float, float]
    setpoint: tuple[float, float, float] | None
    command: DartCommand


@dataclass(frozen=True)
class AttitudeAid:
    """The attitude the vehicle knows, handed to the detector to resolve the IPPE mirror pair
    (``PadDetector.detect(normal_cam=...)``): the true body roll / pitch / yaw plus a constant
    bias (roll +, pitch -, yaw +) and white noise per frame (1 sigma), degrees, as an autopilot or
    Madgwick estimate would be off. The camera attitude follows from it through the nominal
    mount and gimbal (level for a gimbal; its residual error is unknown to the vehicle)."""

    bias_deg: float = 0.5
    noise_deg: float = 1.0
    yaw_bias_deg: float = 2.0

    def __post_init__(self) -> None:
        for name in ("bias_deg", "noise_deg", "yaw_bias_deg"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0.0):
                raise ValueError(f"AttitudeAid.{name} = {v!r}: must be finite and >= 0 (degrees)")


@dataclass(frozen=True)
class DetectionRecord:
    """One detection against the rendered truth: fused (not ambiguous), the position error of the
    chosen pose (marker in the camera frame, m), the error of the camera position in the marker
    frame it implies (-R^T t: what FCF-CF fuses, the rotation error times the distance included),
    its rotation error (deg) and whether it is the wrong one of the mirror pair (farther from the
    true rotation than the alternative by > 2 deg)."""

    time_s: float
    fused: bool
    position_error_m: float
    camera_position_error_m: float
    rotation_error_deg: float
    wrong_choice: bool
    resolved_by: str
    markers: tuple[str, ...]


@dataclass
class DartRunStats:
    frames: int = 0
    detections: int = 0
    ambiguous: int = 0
    estimates: int = 0
    imu_samples: int = 0
    max_blur_px: float = 0.0


class BlockNoise:
    """Standard normal draws in blocks (one rng call per block: fast in the physics loop)."""

    def __init__(self, rng: np.random.Generator, block: int = 4096) -> None:
        self._rng = rng
        self._block = block
        self._buf: list[float] = []
        self._i = 0

    def __call__(self) -> float:
        if self._i >= len(self._buf):
            self._buf = self._rng.standard_normal(self._block).tolist()
            self._i = 0
        v = self._buf[self._i]
        self._i += 1
        return v


def motion_blur(img: NDArray[np.uint8], du: float, dv: float) -> NDArray[np.uint8]:
    """Line blur along the image motion (du, dv) pixels during the exposure."""
    length = math.hypot(du, dv)
    n = math.ceil(length) | 1
    k = np.zeros((n, n), np.float32)
    c = n // 2
    for s in np.linspace(-0.5, 0.5, 4 * n):
        k[round(c + s * dv), round(c + s * du)] = 1.0
    return np.asarray(cv2.filter2D(img, -1, k / k.sum(), borderType=cv2.BORDER_REPLICATE), dtype=np.uint8)


# ------------------------------------------------------------------------------ the simulation
class DartSim:
    """One Dart flight: ``run_until(t)`` advances the lock-step simulation.

    ``estimator``: "FCF-CF", "FCF-MF", "SCF-MF-2DOF" or "SCF-MF-3DOF"; ``gimbal`` defaults to
    the paper's pairing (ESTIMATOR_GIMBAL). ``pilot``: time -> RC channels (neutral sticks,
    switch on by default).
    """

    def __init__(
        self,
        estimator: str,
        config: DartSimConfig | None = None,
        mission: DartMissionConfig | None = None,
        *,
        gimbal: GimbalKind | None = None,
        seed: int = 0,
        pilot: PilotFn = neutral_pilot,
        controller: DartControllerConfig | None = None,
        rates: DartTaskRates | None = None,
        camera: CameraModel | None = None,
        attitude_aid: AttitudeAid | None = None,
        estimator_table: DartEstimatorTable | None = None,
    ) -> None:
        self.config = c = config or DartSimConfig()
        self.estimator_table = estimator_table or DartEstimatorTable()  # [estimator] of a Dart file
        self.attitude_aid = attitude_aid
        self._rng_aid = np.random.default_rng(np.random.SeedSequence([seed, 0xA77]))
        self.detection_log: list[DetectionRecord] = []
        self.rates = rates or DartTaskRates()
        self.pilot = pilot
        self.seed = seed
        self.estimator: DartEstimator = make_estimator(estimator, self._estimator_config())
        self.name = self.estimator.name
        self.gimbal = gimbal if gimbal is not None else ESTIMATOR_GIMBAL[self.name]
        self.mission = DartMission(mission or DartMissionConfig(approach=False, hover_s=1e9))
        self.controller = DartController(controller or controller_config(DartControlGains(), self.rates.control_hz))
        self.mixer_config = RcMixerConfig()
        self.mixer = RcMixer(self.mixer_config, on_disengage=self.controller.disengage)
        self.attitude_map: AttitudeMapConfig = c  # [sim] is an attitude map (param_kinds.AttitudeMapTable)
        ss = np.random.SeedSequence(seed)
        s_phys, s_imu, s_cam, s_render = ss.spawn(4)
        self._n_phys = BlockNoise(np.random.default_rng(s_phys))
        self._n_imu = BlockNoise(np.random.default_rng(s_imu))
        self._rng_cam = np.random.default_rng(s_cam)
        # camera, marker, detector
        cam = camera
        if cam is None:
            from companion.vision.camera import load_camera

            cam = load_camera(c.camera_file) if c.camera_file else load_default_camera()
        if c.camera_scale != 1.0:
            cam = cam.scaled(c.camera_scale)
        self.camera_model = cam
        self._R_bc = np.array(camera_mount(), dtype=float)
        self._t_bc = np.array(c.lens_offset_m, dtype=float)
        self._R_wm = np.array(wall_marker(0.0), dtype=float)
        layout = c.layout
        self.camera = SimulatedCamera(
            cam,
            layout,
            SimCameraConfig(
                latency_s=c.camera_latency_s,
                noise_std=0.0,
                ground_size_m=c.wall_size_m,
                clutter=c.wall_clutter,
                clutter_radius_m=0.45 * c.wall_size_m,
            ),
            T_body_camera=Transform(self._R_bc, self._t_bc),
            T_world_pad=Transform(self._R_wm, np.zeros(3)),
            seed=int(s_render.generate_state(1)[0]),
        )
        self.detector = PadDetector(cam, layout)
        w, h = cam.size
        self._noise_img = (self._rng_cam.standard_normal((h + 64, w + 64)) * c.image_noise_std).astype(np.float32)
        self._f_px = 0.5 * (cam.fx + cam.fy)
        # IMU biases, vibration phases
        self._gyro_bias = [c.gyro_bias_rad_s * self._n_imu() for _ in range(3)]
        self._accel_bias = [c.accel_bias_m_s2 * self._n_imu() for _ in range(3)]
        self._vib_phase = [2.0 * math.pi * float(self._rng_cam.uniform()) for _ in range(6)]
        # state: world NED position/velocity of the CoT, controlled attitude, disturbance
        sp = self.mission.start_setpoint
        p0_m = np.array([sp.x_m, sp.y_m, sp.z_m]) + np.array(c.start_offset_m)
        p0 = self._R_wm @ p0_m
        self.t = 0.0
        self.pos = [float(p0[0]), float(p0[1]), float(p0[2])]
        self.vel = [0.0, 0.0, 0.0]
        self.roll_c = self.pitch_c = 0.0
        self.yaw = 0.0
        self.yaw_rate = 0.0
        self.dist = [0.0, 0.0, 0.0]  # attitude disturbance (roll, pitch, yaw), smoothed
        self.dist_gm = [0.0, 0.0, 0.0]  # its Gauss-Markov driver
        self.gust = [0.0, 0.0, 0.0]
        self.gimbal_err = [0.0, 0.0, 0.0]  # camera attitude error of the gimbal axes
        self._att_prev = (0.0, 0.0, 0.0)
        self.euler_rate = (0.0, 0.0, 0.0)
        self.accel = [0.0, 0.0, 0.0]  # world acceleration of the last physics step
        # tasks
        self._dt = 1.0 / c.physics_hz
        self._next_imu = 0.0
        self._next_cam = 0.5 / self.rates.vision_hz
        self._next_ctl = 0.0
        self._next_cmd = 0.0
        self._pending: deque[tuple[float, CameraMarkerObservation | None]] = deque()
        self.command = DartCommand(0.0, 0.0, 0.0, 0.0, 0.0, engaged=False)
        self.override: tuple[int | None, ...] | None = None  # RC override in force (None: released)
        self.samples: list[DartSample] = []
        self.stats = DartRunStats()
        self.last_setpoint: DartSetpoint | None = None
        self.rc_in: tuple[float, float, float, float] = (NEUTRAL_US,) * 4  # what the FC flies on

    def _estimator_config(self) -> DartEstimatorConfig:
        return DartEstimatorConfig.with_geometry(
            self.estimator_table,
            R_body_cam=camera_mount(),
            t_body_cam_m=tuple(self.config.lens_offset_m),  # type: ignore[arg-type]
            R_world_marker=wall_marker(0.0),
        )

    # ---------------------------------------------------------------- truth
    def attitude(self, t: float | None = None) -> tuple[float, float, float]:
        """True body attitude (roll, pitch, yaw) including the vibration angles at time t."""
        c = self.config
        t = self.t if t is None else t
        a = c.gyro_vibration_rad_s / (2.0 * math.pi * c.vibration_hz)
        w = 2.0 * math.pi * c.vibration_hz * t
        ph = self._vib_phase
        return (
            self.roll_c + self.dist[0] - a * math.cos(w + ph[0]),
            self.pitch_c + self.dist[1] - a * math.cos(w + ph[1]),
            self.yaw + self.dist[2] - a * math.cos(w + ph[2]),
        )

    def T_world_body(self) -> Transform:
        return Transform(euler_to_rotmat(*self.attitude()), np.array(self.pos))

    def truth_marker(self) -> tuple[float, float, float]:
        """The centre of thrust in the marker frame (x right, y up, z out of the wall)."""
        p = self._R_wm.T @ np.array(self.pos)
        return (float(p[0]), float(p[1]), float(p[2]))

    def T_world_camera(self) -> Transform:
        roll, pitch, yaw = self.attitude()
        R_wb = euler_to_rotmat(roll, pitch, yaw)
        e = self.gimbal_err
        if self.gimbal is GimbalKind.NONE:
            R_wc = R_wb @ self._R_bc
        elif self.gimbal is GimbalKind.TWO_DOF:
            R_wc = euler_to_rotmat(e[0], e[1], yaw) @ self._R_bc
        else:
            R_wc = euler_to_rotmat(e[0], e[1], e[2]) @ self._R_bc  # holds heading 0 (gimbal_yaw_rad)
        return Transform(R_wc, np.array(self.pos) + R_wb @ self._t_bc)

    # ---------------------------------------------------------------- physics
    def _sticks(self) -> tuple[float, float, float, float]:
        if self.override is not None:
            return tuple(float(v) if v is not None else NEUTRAL_US for v in self.override)  # type: ignore[return-value]
        p = self.pilot(self.t)
        ch = self.mixer_config.channels
        return tuple(float(p[i - 1]) for i in ch)  # type: ignore[return-value]

    def _physics_step(self) -> None:
        c = self.config
        dt = self._dt
        n = self._n_phys
        sticks = self._sticks()
        self.rc_in = sticks
        chans = [NEUTRAL_US] * 8
        for ch, v in zip(self.mixer_config.channels, sticks, strict=True):
            chans[ch - 1] = v
        sp = attitude_setpoint(chans, None, self.mixer_config, self.attitude_map)
        if sp is None:  # invalid sticks: the FC levels and holds (failsafe-like)
            roll_sp = pitch_sp = yaw_rate_sp = 0.0
            thrust = c.hover_throttle if c.throttle_mode == "thrust" else 0.5
        else:
            roll_sp, pitch_sp, yaw_rate_sp, thrust = sp.roll_rad, sp.pitch_rad, sp.yaw_rate_rad_s, sp.thrust
        (r_roll, r_pitch, r_yaw), d_rate, self.yaw_rate = attitude_response(
            c,
            dt,
            (self.roll_c, self.pitch_c, self.yaw_rate),
            (roll_sp, pitch_sp, yaw_rate_sp),
            self.dist,
            self.dist_gm,
            n,
        )
        self.euler_rate = (r_roll + d_rate[0], r_pitch + d_rate[1], r_yaw + d_rate[2])
        self.roll_c += r_roll * dt
        self.pitch_c += r_pitch * dt
        self.yaw += r_yaw * dt
        phi_g = math.exp(-dt / c.gust_tau_s)
        sg = c.gust_std_m_s * math.sqrt(1.0 - phi_g * phi_g)
        for i in range(3):
            self.gust[i] = phi_g * self.gust[i] + (0.5 if i == 2 else 1.0) * sg * n()
        att = (self.roll_c + self.dist[0], self.pitch_c + self.dist[1], self.yaw + self.dist[2])
        self._att_prev = att
        roll, pitch, yaw = att
        cr, sr = math.cos(roll), math.sin(roll)
        cp, sp_ = math.cos(pitch), math.sin(pitch)
        cy, sy = math.cos(yaw), math.sin(yaw)
        # thrust per mass
        vd = self.vel[2]
        f_t = thrust_per_mass(c, c.throttle_mode, thrust, vd, cr * cp)
        # body -z in world: third column of R_wb, negated
        bz = (cy * sp_ * cr + sy * sr, sy * sp_ * cr - cy * sr, cp * cr)
        wind = c.wind_ned_m_s
        acc = [0.0, 0.0, 0.0]
        for i in range(3):
            air = self.vel[i] - wind[i] - self.gust[i]
            acc[i] = -f_t * bz[i] - c.drag_per_s * air + (G if i == 2 else 0.0)
        for i in range(3):
            self.vel[i] += acc[i] * dt
            self.pos[i] += self.vel[i] * dt
        self.accel = acc
        # gimbal axes: dragged by the body's rotation, restored by the motors
        kg = dt / c.gimbal_tau_s
        er = self.euler_rate
        for i in range(3):
            self.gimbal_err[i] += c.gimbal_coupling * er[i] * dt - kg * self.gimbal_err[i]
        self.t += dt

    # ---------------------------------------------------------------- sensors
    def imu_reading(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """The IMU's reading now: body rates (rad/s) and specific force (m/s^2), with the
        configured bias, noise and vibration (a noisy IMU draws from the sim's generator: a
        reading taken outside the run shifts the run's later draws)."""
        return self._imu()

    def _imu(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        c = self.config
        n = self._n_imu
        roll, pitch, _ = self._att_prev
        dr, dp, dy = self.euler_rate
        sr, cr = math.sin(roll), math.cos(roll)
        sp, cp = math.sin(pitch), math.cos(pitch)
        # body rates from ZYX Euler rates
        p = dr - sp * dy
        q = cr * dp + sr * cp * dy
        r = -sr * dp + cr * cp * dy
        w = 2.0 * math.pi * c.vibration_hz * self.t
        ph = self._vib_phase
        gv, av = c.gyro_vibration_rad_s, c.accel_vibration_m_s2
        gyro = tuple(
            rate + self._gyro_bias[i] + c.gyro_noise_rad_s * n() + gv * math.sin(w + ph[i])
            for i, rate in enumerate((p, q, r))
        )
        R_wb = euler_to_rotmat(*self.attitude())
        spec = R_wb.T @ np.array([self.accel[0], self.accel[1], self.accel[2] - G])
        accel = tuple(
            float(spec[i]) + self._accel_bias[i] + c.accel_noise_m_s2 * n() + av * math.sin(w + ph[3 + i])
            for i in range(3)
        )
        return gyro, accel  # type: ignore[return-value]

    def _camera_rate_cam(self) -> FloatArray:
        """Angular rate of the camera in camera axes (for the motion blur)."""
        c = self.config
        w = 2.0 * math.pi * c.vibration_hz * self.t
        vib = [c.gyro_vibration_rad_s * math.sin(w + self._vib_phase[i]) for i in range(3)]
        er = self.euler_rate
        if self.gimbal is GimbalKind.NONE:
            body = np.array([er[0] + vib[0], er[1] + vib[1], er[2] + vib[2]])
        else:  # a gimbal axis moves at its error rate; vibration is isolated
            kg = 1.0 / c.gimbal_tau_s
            body = np.array([c.gimbal_coupling * er[i] - kg * self.gimbal_err[i] for i in range(3)])
            if self.gimbal is GimbalKind.TWO_DOF:
                body[2] = er[2] + vib[2]
        return self._R_bc.T @ body

    def _capture(self) -> None:
        c = self.config
        t_exp = self.t
        T_wc = self.T_world_camera()
        if self.gimbal is not GimbalKind.NONE and c.gimbal_noise_deg > 0.0:
            e = np.radians(c.gimbal_noise_deg) * self._rng_cam.standard_normal(3)
            if self.gimbal is GimbalKind.TWO_DOF:
                e[2] = 0.0
            T_wc = Transform(euler_to_rotmat(*e) @ T_wc.R, T_wc.t)
        frame = self.camera.capture_camera(T_wc, t_exp)
        img = frame.image
        wc = self._camera_rate_cam()
        du = self._f_px * float(wc[1]) * c.exposure_s
        dv = -self._f_px * float(wc[0]) * c.exposure_s
        blur = math.hypot(du, dv)
        self.stats.max_blur_px = max(self.stats.max_blur_px, blur)
        if blur >= 0.5:
            img = motion_blur(img, du, dv)
        if c.image_noise_std > 0.0:
            h, w = img.shape
            oy, ox = (int(v) for v in self._rng_cam.integers(0, 64, 2))
            img = np.clip(img.astype(np.float32) + self._noise_img[oy : oy + h, ox : ox + w], 0, 255).astype(np.uint8)
        self.stats.frames += 1
        if self.attitude_aid is None:
            obs = self.detector.detect(img, t_exp)
        else:
            obs = self.detector.detect(img, t_exp, normal_cam=self._normal_cam_from_attitude())
        if obs is not None:
            self._record_detection(obs, frame.T_camera_pad)
        cobs = self._to_estimator(obs)
        self._pending.append((frame.available_time_s, cobs))

    def _normal_cam_from_attitude(self) -> FloatArray:
        """The wall marker's normal in the camera frame from the attitude the vehicle knows."""
        aid = self.attitude_aid
        assert aid is not None
        roll, pitch, yaw = self.attitude()
        b, sd = math.radians(aid.bias_deg), math.radians(aid.noise_deg)
        n = self._rng_aid.standard_normal(3)
        roll_e = roll + b + sd * float(n[0])
        pitch_e = pitch - b + sd * float(n[1])
        yaw_e = yaw + math.radians(aid.yaw_bias_deg) + sd * float(n[2])
        if self.gimbal is GimbalKind.NONE:
            R_wc = euler_to_rotmat(roll_e, pitch_e, yaw_e) @ self._R_bc
        elif self.gimbal is GimbalKind.TWO_DOF:
            R_wc = euler_to_rotmat(0.0, 0.0, yaw_e) @ self._R_bc
        else:
            R_wc = euler_to_rotmat(0.0, 0.0, 0.0) @ self._R_bc
        return marker_normal_in_camera(R_wc, self._R_wm[:, 2])

    def _record_detection(self, obs: MarkerObservation, truth: Transform) -> None:
        err_R = rotation_angle(obs.T_camera_pad.R, truth.R)
        wrong = obs.alternative is not None and err_R > rotation_angle(obs.alternative.R, truth.R) + math.radians(2.0)
        self.detection_log.append(
            DetectionRecord(
                time_s=obs.time_s,
                fused=not obs.ambiguous,
                position_error_m=float(np.linalg.norm(obs.T_camera_pad.t - truth.t)),
                camera_position_error_m=float(
                    np.linalg.norm(obs.T_camera_pad.R.T @ obs.T_camera_pad.t - truth.R.T @ truth.t)
                ),
                rotation_error_deg=math.degrees(err_R),
                wrong_choice=bool(wrong),
                resolved_by=obs.resolved_by,
                markers=tuple(obs.markers),
            )
        )

    def _to_estimator(self, obs: MarkerObservation | None) -> CameraMarkerObservation | None:
        if obs is None:
            return None
        self.stats.detections += 1
        if obs.ambiguous:
            self.stats.ambiguous += 1
        return CameraMarkerObservation.from_detection(obs)  # an ambiguous one is gated by the estimator

    # ---------------------------------------------------------------- tasks
    def _control(self) -> None:
        t = self.t
        engaged = self.mixer.engaged_from(self.pilot(t))
        step = self.mission.update(t, engaged)
        sp = step.setpoint or self.last_setpoint or self.mission.start_setpoint
        self.last_setpoint = sp
        est: DartPositionEstimate | None = self.estimator.last
        self.command = self.controller.update(t, est, sp, engaged)
        e = (math.nan, math.nan, math.nan) if est is None else (est.x_m, est.y_m, est.z_m)
        self.samples.append(
            DartSample(t, engaged, e, self.truth_marker(), (sp.x_m, sp.y_m, sp.z_m) if engaged else None, self.command)
        )

    def _command(self) -> None:
        out = self.mixer.mix(self.pilot(self.t), self.command)
        self.override = out.sticks_us if out.engaged else None

    def run_until(self, t_end: float) -> None:
        """Advance the simulation to ``t_end`` (seconds of simulated time)."""
        r = self.rates
        eps = 1e-9
        while self.t < t_end - eps:
            self._physics_step()
            t = self.t
            if t >= self._next_imu - eps:
                self._next_imu += 1.0 / r.imu_hz
                g, a = self._imu()
                self.estimator.update_imu(t, g, a)
                self.stats.imu_samples += 1
            while self._pending and self._pending[0][0] <= t + eps:
                _, obs = self._pending.popleft()
                if obs is not None and self.estimator.update_vision(obs) is not None:
                    self.stats.estimates += 1
            if t >= self._next_cam - eps:
                self._next_cam += 1.0 / r.vision_hz
                self._capture()
            if t >= self._next_ctl - eps:
                self._next_ctl += 1.0 / r.control_hz
                self._control()
            if t >= self._next_cmd - eps:
                self._next_cmd += 1.0 / r.command_hz
                self._command()

    # ---------------------------------------------------------------- results
    def errors(self, t_from: float = 0.0, *, truth: bool = False) -> NDArray[np.float64]:
        """(N, 3) position errors (estimate or truth minus setpoint, marker axes) of the engaged
        control steps from ``t_from`` on; steps without an estimate are left out."""
        rows = []
        for s in self.samples:
            if s.time_s < t_from or not s.engaged or s.setpoint is None or not math.isfinite(s.est[0]):
                continue
            p = s.truth if truth else s.est
            rows.append([p[i] - s.setpoint[i] for i in range(3)])
        return np.array(rows, dtype=float).reshape(-1, 3)


def run_hover(
    estimator: str,
    duration_s: float,
    *,
    seed: int = 0,
    config: DartSimConfig | None = None,
    **kwargs: Any,
) -> DartSim:
    """A hover flight of ``duration_s`` at the mission's start point; returns the finished sim."""
    sim = DartSim(estimator, config, DartMissionConfig(approach=False, hover_s=0.0), seed=seed, **kwargs)
    sim.run_until(duration_s)
    return sim


__all__ = [
    "ESTIMATOR_GIMBAL",
    "DartControlGains",
    "DartParams",
    "DartRunStats",
    "DartSample",
    "DartSim",
    "DartSimConfig",
    "load_dart_params",
    "neutral_pilot",
    "pilot_channels",
    "run_hover",
    "shipped_dart_params",
]
