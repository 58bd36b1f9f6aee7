"""Landing fusion: the autopilot's GPS pose, pad observations and UWB fixes in the 12-state EKF.

Pure and synchronous (the shell feeds it samples). Inputs (delivery 4.2.3): u = world velocity
(from the autopilot's local velocity) and body rates (from ATTITUDE). The autopilot pose is the
h_SDK measurement (eq 12); marker observations are fused as the pad's pose in the camera frame
(eqs 13-14) at their *exposure* time through the delayed-measurement buffer (camera latency is
what made the Dart drone oscillate); UWB fixes as positions in the anchor frame (eq 15).

The resulting position is in the frame where the pad sits at its *configured* position: the GPS
bias state absorbs both the GPS error and a displaced pad (delivery 5.2), so guidance towards
the configured pad lands on the real one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from companion.autopilot.types import Attitude, PositionNed, TelemetrySample
from companion.config import MovingPadConfig
from companion.delivery.attitude_history import AttitudeHistory
from companion.delivery.pad_heading import PadHeadingEstimator
from companion.delivery.pad_tilt import PadTiltEstimator
from companion.delivery.padlock import PAD_DATA_FRESH_S
from companion.estimation.delayed import DelayedMeasurementBuffer
from companion.estimation.ekf import DeliveryEkf, EkfConfig, EkfSensor, UpdateOutcome
from companion.estimation.moving_pad import MovingPadEkf
from companion.estimation.types import StateEstimate
from companion.geometry.heading import pad_heading_rad
from companion.geometry.mounts import pad_pose_ned
from companion.geometry.rotations import euler_to_rotmat
from companion.geometry.se3 import Transform
from companion.guidance.velocity_bias import VelocityBiasCorrection

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FusionSetup:
    T_world_pad: Transform  # the pad's configured pose in world NED (pad frame: x E, y N, z up)
    T_body_camera: Transform
    T_pad_anchors: Transform = field(default_factory=Transform.identity)  # UWB anchor frame in the pad frame
    ekf: EkfConfig = field(default_factory=EkfConfig)
    history_s: float = 1.0  # how late a measurement may arrive and still be applied at its stamp
    # a pad with a heading (mission.pad.heading_deg, in T_world_pad's yaw): the camera measures it
    # (delivery.pad_heading) within this bound of the configured one; None: no heading measured
    heading_tolerance_rad: float | None = None
    # > 0: the autopilot's velocity, the EKF's process input, is corrected by its bias
    # (guidance.velocity_bias, low-passed with this time constant, at most velocity_bias_max_m_s),
    # measured against velocity_bias_source's position; 0: taken as reported
    velocity_bias_tau_s: float = 0.0
    velocity_bias_max_m_s: float = 1.0
    velocity_bias_source: str = "autopilot"  # or "fusion": against this fusion's own position once locked
    # the pad lies level: its tilt as the camera sees it is taken out of the autopilot's attitude
    # before the EKF fuses it (delivery.pad_tilt)
    level_pad: bool = False
    # the pad may move ([landing.moving_pad]): the EKF also estimates its horizontal velocity
    # (estimation.moving_pad, 14 states); None: the paper's 12-state filter
    moving_pad: MovingPadConfig | None = None


@dataclass
class FusionCounters:
    markers_used: int = 0
    markers_ambiguous: int = 0
    uwb_used: int = 0
    # "sensor.outcome" -> count (EkfSensor's and UpdateOutcome's values: "sdk.accepted"), as
    # written out (campaign JSON); the two totals below are counted from the enums, not this text
    outcomes: dict[str, int] = field(default_factory=dict)
    accepted: int = 0  # updates of any sensor the EKF accepted
    rejected: int = 0  # and those it did not (any UpdateOutcome but ACCEPTED)

    def count(self, sensor: EkfSensor, outcome: UpdateOutcome) -> None:
        k = f"{sensor.value}.{outcome.value}"
        self.outcomes[k] = self.outcomes.get(k, 0) + 1
        if outcome is UpdateOutcome.ACCEPTED:
            self.accepted += 1
        else:
            self.rejected += 1


@dataclass(frozen=True)
class PadSighting:
    """The last pad observation the EKF accepted: exposure time, the markers used and the pad
    centre relative to the vehicle in world NED axes (the camera's measurement turned by the
    EKF attitude), metres."""

    time_s: float
    markers: tuple[str, ...]
    pad_rel_ned_m: tuple[float, float, float]


class LandingFusion:
    def __init__(self, setup: FusionSetup, start_time_s: float):
        self.setup = setup
        pad_down_m = float(setup.T_world_pad.t[2])
        self.ekf: DeliveryEkf = (
            DeliveryEkf(setup.ekf, T_body_camera=setup.T_body_camera, pad_down_m=pad_down_m)
            if setup.moving_pad is None
            else MovingPadEkf(setup.ekf, setup.moving_pad, T_body_camera=setup.T_body_camera, pad_down_m=pad_down_m)
        )
        self.buffer = DelayedMeasurementBuffer(self.ekf, start_time_s, history_s=setup.history_s)
        self.T_world_pad = setup.T_world_pad  # its rotation follows the measured pad heading
        self.T_world_anchors = setup.T_world_pad @ setup.T_pad_anchors
        self.attitudes = AttitudeHistory()  # for the estimators that need the attitude at an exposure
        self.heading: PadHeadingEstimator | None = None
        if setup.heading_tolerance_rad is not None:
            self.heading = PadHeadingEstimator(
                pad_heading_rad(setup.T_world_pad.R), setup.heading_tolerance_rad, attitudes=self.attitudes
            )
        self.tilt = PadTiltEstimator(self.attitudes) if setup.level_pad else None
        self.counters = FusionCounters()
        self._vel = np.zeros(3)
        self._vel_bias = (
            VelocityBiasCorrection(setup.velocity_bias_tau_s, setup.velocity_bias_max_m_s, setup.velocity_bias_source)
            if setup.velocity_bias_tau_s > 0.0
            else None
        )
        self._rates = np.zeros(3)
        self._euler: np.ndarray | None = None
        self._last_marker_s = -np.inf
        # a moving pad: its estimated travel (north, east m) since the lock, and when last summed
        self._pad_travel: tuple[float | None, float, float] = (None, 0.0, 0.0)
        self._last_uwb_s = -np.inf
        self.last_sighting: PadSighting | None = None
        self.last_uwb_fix: object | None = None  # the last accepted uwb.UwbFix

    # ---- inputs --------------------------------------------------------------------------
    def on_sample(self, sample: TelemetrySample) -> None:
        """TelemetryCache listener: autopilot attitude and position (already finite-checked)."""
        if isinstance(sample, Attitude):
            self._rates = np.array([sample.rollspeed_rad_s, sample.pitchspeed_rad_s, sample.yawspeed_rad_s])
            self._euler = np.array([sample.roll_rad, sample.pitch_rad, sample.yaw_rad])
            if self.heading is not None or self.tilt is not None:
                self.attitudes.add(sample.time_s, sample.roll_rad, sample.pitch_rad, sample.yaw_rad)
            self._predict(sample.time_s)
        elif isinstance(sample, PositionNed):
            self._vel = np.array([sample.north_m_s, sample.east_m_s, sample.down_m_s])
            if self._vel_bias is not None:
                # an autopilot whose velocity estimate drifts from its own GPS-held position (PX4 SIH
                # near the ground, docs/firmware-px4.md) would otherwise carry the EKF's position off
                # by bias x (camera latency + filter lag) between pad observations
                self._vel = self._vel + np.asarray(self._vel_bias.update(sample, self.locked_position))
            self._predict(sample.time_s)
            euler = self._euler
            if self.tilt is not None and euler is not None:
                euler = self.tilt.corrected(euler)
            out = self.buffer.update_sdk(sample.time_s, (sample.north_m, sample.east_m, sample.down_m), euler)
            self.counters.count(EkfSensor.SDK, out)

    def _predict(self, t: float) -> None:
        if t >= self.buffer.now_s:
            self.buffer.predict(t, np.concatenate([self._vel, self._rates]))

    def on_marker(self, obs: object) -> UpdateOutcome | None:
        """A :class:`companion.vision.MarkerObservation` (pad pose in the camera, exposure-stamped)."""
        if getattr(obs, "ambiguous", False):
            self.counters.markers_ambiguous += 1
            return None  # never fused blindly (the IPPE flip)
        if self.heading is not None:
            self._measure_heading(obs)
        if self.tilt is not None:
            self.tilt.on_observation(obs.time_s, obs.T_camera_pad.R, self.setup.T_body_camera.R)  # type: ignore[attr-defined]
        out = self.buffer.update_aruco(obs.time_s, obs.T_camera_pad, self.T_world_pad)  # type: ignore[attr-defined]
        self.counters.count(EkfSensor.ARUCO, out)
        if out is UpdateOutcome.ACCEPTED:
            self.counters.markers_used += 1
            self._last_marker_s = obs.time_s  # type: ignore[attr-defined]
            self.last_sighting = self._sighting(obs)
        return out

    def _measure_heading(self, obs: object) -> None:
        """The pad's heading from this observation; once measured, the pad's pose the EKF fuses
        against (and the anchors fixed to it) turns to it: a dock placed a few degrees off its
        configured heading would otherwise pull the EKF's yaw by that much."""
        assert self.heading is not None
        T_camera_pad: Transform = obs.T_camera_pad  # type: ignore[attr-defined]
        if not self.heading.on_observation(obs.time_s, T_camera_pad.R, self.setup.T_body_camera.R):  # type: ignore[attr-defined]
            return
        h = self.heading.measured_rad
        if h is None:
            return
        T = self.setup.T_world_pad
        self.T_world_pad = pad_pose_ned(float(T.t[0]), float(T.t[1]), float(T.t[2]), yaw_rad=h)
        self.T_world_anchors = self.T_world_pad @ self.setup.T_pad_anchors

    def _sighting(self, obs: object) -> PadSighting:
        T_camera_pad: Transform = obs.T_camera_pad  # type: ignore[attr-defined]
        p_body = self.setup.T_body_camera.R @ T_camera_pad.t + self.setup.T_body_camera.t
        x = self.ekf.x
        rel = euler_to_rotmat(float(x[3]), float(x[4]), float(x[5])) @ p_body
        return PadSighting(
            float(obs.time_s),  # type: ignore[attr-defined]
            tuple(getattr(obs, "markers", ())),
            (float(rel[0]), float(rel[1]), float(rel[2])),
        )

    def on_uwb(self, fix: object) -> UpdateOutcome:
        out = self.buffer.update_uwb(fix, self.T_world_anchors)  # type: ignore[arg-type]
        self.counters.count(EkfSensor.UWB, out)
        if out is UpdateOutcome.ACCEPTED:
            self.counters.uwb_used += 1
            self._last_uwb_s = fix.time_s  # type: ignore[attr-defined]
            self.last_uwb_fix = fix
        return out

    # ---- outputs -------------------------------------------------------------------------
    @property
    def process_velocity_ned_m_s(self) -> tuple[float, float, float]:
        """The velocity the EKF predicts with now (N, E, D; m/s): the autopilot's reported one,
        plus the learned correction when [landing] ekf_velocity_bias_tau_s is on."""
        return (float(self._vel[0]), float(self._vel[1]), float(self._vel[2]))

    @property
    def velocity_bias_correction(self) -> VelocityBiasCorrection | None:
        """The correction of a biased autopilot velocity (None when ekf_velocity_bias_tau_s is 0)."""
        return self._vel_bias

    @property
    def pad_velocity_ne(self) -> tuple[float, float] | None:
        """The pad's estimated velocity (north, east; m/s) once pad-local data is fused, with
        [landing.moving_pad] on (None otherwise: the pad stands, or nothing observed it yet)."""
        if not isinstance(self.ekf, MovingPadEkf) or not self.ekf.xi:
            return None
        return self.ekf.pad_velocity_ne

    @property
    def pad_locked(self) -> bool:
        """Pad-local data has been fused (xi = 1, delivery eq 12)."""
        return bool(self.ekf.xi)

    def estimate(self) -> StateEstimate | None:
        if not self.ekf.initialized:
            return None
        return self.buffer.estimate()

    def locked_position(self) -> tuple[float, tuple[float, float, float]] | None:
        """The estimate's time and NED position while pad data keeps coming (the last within
        PAD_DATA_FRESH_S; None otherwise), for the velocity-bias correction against the fused
        position (guidance.velocity_bias.VelocityBiasCorrection): without pad data the fused
        position is only the autopilot's velocity integrated. A moving pad's fused position is
        pad-relative: it is moved on by the pad's estimated travel, so that its rate is the ground
        velocity the autopilot reports (else the bias would take the pad's velocity)."""
        est = self.estimate() if self.pad_locked else None
        if est is None:
            return None
        pos = est.position_ned
        v = self.pad_velocity_ne
        if v is not None:
            t_last, dn, de = self._pad_travel
            dt = est.time_s - t_last if t_last is not None else 0.0
            if dt > 0.0:
                dn, de = dn + v[0] * dt, de + v[1] * dt
            if dt >= 0.0:
                self._pad_travel = (est.time_s, dn, de)
            pos = (pos[0] + dn, pos[1] + de, pos[2])
        if self.pad_data_age_s(est.time_s) > PAD_DATA_FRESH_S:
            return None
        return (est.time_s, pos)

    def pad_data_age_s(self, now_s: float) -> float:
        return now_s - max(self._last_marker_s, self._last_uwb_s)

    def marker_age_s(self, now_s: float) -> float:
        """Since the exposure of the last accepted pad observation (inf: none yet)."""
        return now_s - self._last_marker_s

    def uwb_age_s(self, now_s: float) -> float:
        """Since the last accepted UWB fix (inf: none yet)."""
        return now_s - self._last_uwb_s

    def horizontal_error_to_pad_m(self) -> float | None:
        """Estimated horizontal distance from the vehicle to the pad centre: the fused position
        against the configured pad, which the fused frame puts where the camera/UWB see it.
        None until pad data has been fused (before that it would be the GPS-only guess)."""
        est = self.estimate()
        if est is None or not self.pad_locked:
            return None
        pad = self.setup.T_world_pad.t
        return float(np.hypot(est.north_m - pad[0], est.east_m - pad[1]))
