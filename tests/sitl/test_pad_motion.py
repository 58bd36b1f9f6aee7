"""The simulated moving pad ([sim.pad_motion], companion_sitl.pad_motion): its closed-form track
against its own derivative and hand-computed points, and the simulated camera and UWB seeing the
pad (and its anchors) where it is at each instant."""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from companion.config import ConfigError
from companion.geometry.mounts import pad_pose_ned
from companion.uwb.anchors import load_anchor_layout
from companion.vision.camera import load_default_camera
from companion_sitl.camera import SimulatedCamera
from companion_sitl.clock import run_virtual
from companion_sitl.landing_sensors import SimCameraSource, SimUwbSource, _truth_pose
from companion_sitl.pad_motion import PadTrack, pad_track
from companion_sitl.params import SimPadMotionConfig, simulated_config_from_dict
from companion_sitl.uwb import SimulatedUwb


def _cfg(**kw: float) -> SimPadMotionConfig:
    return SimPadMotionConfig.model_validate(kw)


def test_off_by_default_the_pad_stands() -> None:
    assert simulated_config_from_dict({}).sim.pad_motion == SimPadMotionConfig()
    assert pad_track(SimPadMotionConfig(), 3.0, 4.0) is None


def test_a_bad_value_is_refused_naming_the_key() -> None:
    with pytest.raises(ConfigError, match="speed_m_s"):
        simulated_config_from_dict({"sim": {"pad_motion": {"speed_m_s": -1.0}}})
    with pytest.raises(ConfigError, match="pad_motion"):
        simulated_config_from_dict({"sim": {"pad_motion": {"sped_m_s": 1.0}}})


def test_straight_track_stands_ramps_then_cruises() -> None:
    tr = PadTrack(_cfg(speed_m_s=2.0, course_deg=90.0, accel_m_s2=0.5, start_s=10.0), 5.0, -1.0)
    assert tr.state(9.0) == (5.0, -1.0, 0.0, 0.0, 0.0)  # before start_s
    n, e = tr.ne(12.0)  # 2 s into the ramp: 0.5 * 0.5 * 4 = 1 m east
    assert (n, e) == pytest.approx((5.0, 0.0), abs=1e-12)
    # up to speed after 4 s (4 m), then 2 m/s: at t = 20 s, 4 + 12 m east
    assert tr.ne(20.0) == pytest.approx((5.0, -1.0 + 16.0), abs=1e-9)
    assert tr.velocity_ne(20.0) == pytest.approx((0.0, 2.0), abs=1e-12)
    assert tr.max_accel_m_s2 == 0.5


def test_turning_track_is_a_circle_of_radius_speed_over_rate() -> None:
    tr = PadTrack(_cfg(speed_m_s=2.0, course_deg=0.0, turn_rate_deg_s=10.0, accel_m_s2=1.0), 0.0, 0.0, 0.3)
    t_circle = 360.0 / 10.0
    start = tr.ne(2.0)  # up to speed after 2 s (2 m north)
    assert start == pytest.approx((2.0, 0.0), abs=1e-12)
    assert tr.ne(2.0 + t_circle) == pytest.approx(start, abs=1e-9)  # a full circle
    r = 2.0 / math.radians(10.0)
    assert tr.ne(2.0 + t_circle / 2.0) == pytest.approx((2.0, 2.0 * r), abs=1e-9)  # turned right: east of it
    _, _, yaw, _, _ = tr.state(2.0 + 9.0)  # the heading turns with the course
    assert yaw == pytest.approx(0.3 + math.radians(90.0), abs=1e-12)
    assert tr.max_accel_m_s2 == max(1.0, 2.0 * math.radians(10.0))


@pytest.mark.parametrize("turn", [0.0, 12.0, -7.0])
def test_velocity_is_the_derivative_of_the_position(turn: float) -> None:
    tr = PadTrack(_cfg(speed_m_s=3.0, course_deg=35.0, turn_rate_deg_s=turn, accel_m_s2=0.8, start_s=1.0), 1.0, 2.0)
    h = 1e-5
    for t in (0.5, 1.7, 4.0, 4.75, 9.0, 30.0):
        (n1, e1), (n0, e0) = tr.ne(t + h), tr.ne(t - h)
        assert tr.velocity_ne(t) == pytest.approx(((n1 - n0) / (2 * h), (e1 - e0) / (2 * h)), abs=1e-5)
        if t > 1.0 + 3.0 / 0.8:  # up to speed
            assert math.hypot(*tr.velocity_ne(t)) == pytest.approx(3.0, abs=1e-12)


def test_pose_is_the_pad_pose_where_the_pad_is() -> None:
    tr = PadTrack(_cfg(speed_m_s=2.0, turn_rate_deg_s=5.0), 1.0, 2.0, 0.2)
    n, e, yaw, _, _ = tr.state(17.0)
    T = tr.pose(17.0)
    ref = pad_pose_ned(n, e, 0.0, yaw_rad=yaw)
    assert np.allclose(T.R, ref.R) and np.allclose(T.t, ref.t)
    s = tr.standing_pose()
    assert np.allclose(s.t, [1.0, 2.0, 0.0]) and np.allclose(s.R, pad_pose_ned(yaw_rad=0.2).R)


class _Hover:
    """A vehicle hovering 6 m up, north of the pad's start, which drives under it."""

    pn, pe, pd, roll, pitch, yaw = 1.0, 0.0, -6.0, 0.0, 0.0, 0.0

    def step_to(self, t: float) -> None:
        pass


def test_the_camera_sees_the_pad_where_it_is_at_each_exposure() -> None:
    tr = PadTrack(_cfg(speed_m_s=2.0, accel_m_s2=2.0), 0.0, 0.0)

    async def read_for(duration_s: float) -> list[tuple[float, np.ndarray]]:
        src = SimCameraSource(  # type: ignore[arg-type]
            _Hover(), SimulatedCamera(load_default_camera(), seed=4), 30.0, 0.05, pad_track=tr
        )
        src.start()
        out = []
        for _ in range(round(duration_s / 0.05)):
            await asyncio.sleep(0.05)
            f = src.read()
            if f is not None:
                out.append((f.time_s, f.image))
        src.stop()
        return out

    frames = run_virtual(read_for(1.5))
    assert len(frames) > 15
    twin = SimulatedCamera(load_default_camera(), seed=4)  # renders each frame on read, in the same order
    for t, image in frames:  # each frame shows the pad where it was at the frame's exposure
        twin.T_world_pad = tr.pose(t)
        assert np.array_equal(image, twin.capture(_truth_pose(_Hover()), t).image), t
    assert tr.ne(frames[-1][0])[0] > 1.0  # the pad moved over a metre while the frames were read


def test_a_moving_pad_frame_differs_from_the_standing_pads() -> None:
    tr = PadTrack(_cfg(speed_m_s=2.0, accel_m_s2=2.0), 0.0, 0.0)
    standing = SimulatedCamera(load_default_camera(), seed=4)
    moved = SimulatedCamera(load_default_camera(), seed=4, T_world_pad=tr.pose(1.5))
    T = _truth_pose(_Hover())
    p_standing, p_moved = standing.T_camera_pad(T).t, moved.T_camera_pad(T).t
    # the pad drove 2 m north (1 m speeding up, 0.5 s at 2 m/s): the camera sees it 2 m off
    assert np.linalg.norm(p_standing - p_moved) == pytest.approx(2.0, abs=1e-9)


def test_the_uwb_anchors_move_with_the_pad() -> None:
    anchors = load_anchor_layout()
    tr = PadTrack(_cfg(speed_m_s=2.0, course_deg=90.0, turn_rate_deg_s=8.0, accel_m_s2=1.0), 0.0, 0.0, 0.4)
    T_world_anchors = tr.standing_pose()  # the anchors' frame is the pad's (as landing_sensors places it)
    ideal = SimulatedUwb(anchors, seed=0)

    async def range_for(duration_s: float) -> list:
        src = SimUwbSource(_Hover(), SimulatedUwb(anchors, seed=1), T_world_anchors, 10.0, pad_track=tr)  # type: ignore[arg-type]
        src.start()
        await asyncio.sleep(duration_s)
        out = src.read()
        src.stop()
        return out

    ms = run_virtual(range_for(4.0))
    assert len(ms) >= 30
    tag_world = np.array([_Hover.pn, _Hover.pe, _Hover.pd])
    worst_moving = worst_standing = 0.0
    ids = list(anchors.anchor_ids)
    for m in ms:
        moving = ideal.true_ranges(tr.pose(m.time_s).inverse().apply(tag_world))
        standing = ideal.true_ranges(T_world_anchors.inverse().apply(tag_world))
        for aid, r in zip(m.anchor_ids, m.ranges_m, strict=True):
            k = ids.index(aid)
            worst_moving = max(worst_moving, abs(r - moving[k]))
            worst_standing = max(worst_standing, abs(r - standing[k]))
    assert worst_moving < 0.5  # the ranging noise (and an occasional NLOS path)
    assert worst_standing > 2.0  # the pad drove off (about 6 m in 4 s)


@pytest.mark.parametrize(("pad_north_m", "rides"), [(0.3, True), (5.0, False)])
def test_a_vehicle_resting_on_the_deck_rides_along_and_one_beside_it_does_not(pad_north_m: float, rides: bool) -> None:
    from companion_sitl.params import SimConfig
    from companion_sitl.vehicle import SimVehicle

    v = SimVehicle(SimConfig())  # on the ground at the origin, disarmed
    tr = PadTrack(_cfg(speed_m_s=1.0, course_deg=90.0, turn_rate_deg_s=10.0, accel_m_s2=1.0), pad_north_m, 0.0)
    v.set_pad_track(tr)
    yaw0 = v.yaw
    v.step_to(6.0)
    if rides:  # its offset from the pad kept in the pad's (turning) frame, its heading turned with it
        n, e, yaw, vn, ve = tr.state(v.time_s)
        dy = yaw - 0.0
        off = (-pad_north_m * math.cos(dy), -pad_north_m * math.sin(dy))
        assert (v.pn, v.pe) == pytest.approx((n + off[0], e + off[1]), abs=1e-6)
        assert math.remainder(v.yaw - yaw0 - dy, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        assert (v.vn, v.ve) == pytest.approx((vn, ve), abs=1e-12)
    else:
        assert (v.pn, v.pe) == (0.0, 0.0)


def test_the_track_on_a_clock_of_its_own_and_stopped_dead():
    """A real firmware's harness: the track's t = 0 at the take-off (start_clock; before it the pad
    stands) and the pad stopped at the ground contact (stop_at), standing there from then on."""
    cfg = _cfg(speed_m_s=2.0, course_deg=90.0, accel_m_s2=0.5, start_s=10.0)
    ref, tr = PadTrack(cfg, 5.0, -1.0), PadTrack(cfg, 5.0, -1.0)
    tr.start_clock(None)
    assert tr.state(1e6) == (5.0, -1.0, 0.0, 0.0, 0.0)  # not started: stands
    tr.start_clock(1000.0)
    for t in (5.0, 12.0, 20.0):
        assert tr.state(1000.0 + t) == pytest.approx(ref.state(t), abs=1e-9)
    tr.stop_at(1020.0)
    tr.stop_at(1030.0)  # the first stop is kept
    n, e, _, vn, ve = tr.state(1050.0)
    assert (n, e) == pytest.approx(ref.ne(20.0), abs=1e-9) and (vn, ve) == (0.0, 0.0)
    assert tr.state(1015.0) == pytest.approx(ref.state(15.0), abs=1e-9)  # before the stop: as ever
