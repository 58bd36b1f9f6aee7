"""[runtime] autopilot_attitude_rate_hz / autopilot_position_rate_hz: the rates the companion asks
the autopilot to stream at, on both backends, against the MAVLink sim vehicle over loopback."""

from __future__ import annotations

import asyncio
import logging
from types import SimpleNamespace

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.requests import DEFAULT_STREAM_RATES_HZ, configured_stream_rates
from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.types import Attitude, PositionNed
from companion.config import ConfigError

WIND_MSG_ID = 168


def test_configured_rates_replace_only_the_attitude_and_position_streams():
    assert configured_stream_rates(None, None) == DEFAULT_STREAM_RATES_HZ
    r = configured_stream_rates(20.0, 10.0)
    assert r[30] == r[105] == r[27] == 20.0  # ATTITUDE, HIGHRES_IMU, RAW_IMU
    assert r[32] == r[33] == 10.0  # LOCAL_POSITION_NED, GLOBAL_POSITION_INT
    rest = {k: v for k, v in r.items() if k not in (30, 105, 27, 32, 33)}
    assert rest == {k: v for k, v in DEFAULT_STREAM_RATES_HZ.items() if k not in (30, 105, 27, 32, 33)}
    assert configured_stream_rates(None, 5.0)[30] == DEFAULT_STREAM_RATES_HZ[30]


def _config(mav, **runtime):  # the companion's own config (load_config) with [runtime] keys set
    return mav.shipped_config(simulated=False, runtime=runtime)


def test_from_config_requests_the_configured_rates_with_the_wind_check_beside_them(mav):
    ap = ArduPilotAutopilot.from_config(_config(mav, autopilot_attitude_rate_hz=25.0, autopilot_position_rate_hz=8.0))
    assert ap.stream_rates_hz[30] == 25.0 and ap.stream_rates_hz[33] == 8.0
    cfg = _config(mav, autopilot_attitude_rate_hz=25.0)
    cfg = cfg.model_copy(update={"go_no_go": cfg.go_no_go.model_copy(update={"wind_limit_m_s": 8.0})})
    ap = ArduPilotAutopilot.from_config(cfg)
    assert ap.stream_rates_hz[WIND_MSG_ID] == 2.0 and ap.stream_rates_hz[105] == 25.0
    assert ap.stream_rates_hz[32] == DEFAULT_STREAM_RATES_HZ[32]
    px4 = Px4Autopilot.from_config(_config(mav, autopilot_position_rate_hz=8.0))
    assert px4.attitude_rate_hz is None and px4.position_rate_hz == 8.0


@pytest.mark.parametrize(("key", "value"), [("autopilot_attitude_rate_hz", 2.0), ("autopilot_position_rate_hz", 500.0)])
def test_a_rate_out_of_range_names_the_key(mav, key, value):
    with pytest.raises(ConfigError, match=key):
        _config(mav, **{key: value})


async def test_px4_asks_for_each_configured_rate_and_a_refusal_is_a_warning(caplog):
    ap = Px4Autopilot("udpin://127.0.0.1:14599")
    asked: list[tuple[str, float]] = []

    def setter(name: str, fail: bool = False):
        async def set_rate(hz: float) -> None:
            asked.append((name, hz))
            if fail:
                raise RuntimeError("UNSUPPORTED")

        return set_rate

    ap._tel = SimpleNamespace(
        set_rate_attitude_euler=setter("attitude"),
        set_rate_attitude_quaternion=setter("quaternion"),
        set_rate_imu=setter("imu", fail=True),
        set_rate_position_velocity_ned=setter("pv"),
        set_rate_position=setter("pos"),
    )
    ap.attitude_rate_hz, ap.position_rate_hz = 20.0, None
    caplog.set_level(logging.INFO, logger="companion.autopilot.px4")
    await ap._set_stream_rates()
    # ATTITUDE_QUATERNION too: MAVSDK's angular velocity stream follows it (onboard mode: 50 Hz);
    # the position streams stay at PX4's rate
    assert asked == [("attitude", 20.0), ("quaternion", 20.0), ("imu", 20.0)]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == ["PX4 did not take IMU at 20 Hz (UNSUPPORTED): it streams at its own rate"]


async def _rates_seen(ap, seconds: float) -> tuple[float, float]:
    att: list[float] = []
    pos: list[float] = []

    def on_sample(s) -> None:
        if isinstance(s, Attitude):
            att.append(s.time_s)
        elif isinstance(s, PositionNed):
            pos.append(s.time_s)

    await asyncio.sleep(1.0)  # the requests answered and the streams settled
    ap.telemetry.add_listener(on_sample)
    await asyncio.sleep(seconds)
    ap.telemetry.remove_listener(on_sample)
    return len(att) / seconds, len(pos) / seconds


@pytest.mark.parametrize("dialect", ["ardupilot", "px4"])
async def test_the_sim_vehicle_streams_at_the_rates_asked_for(mav, udp_port, dialect):
    config = mav.short_config()
    with mav.sim_vehicle(config, dialect, udp_port):
        if dialect == "ardupilot":
            ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}", stream_rates_hz=configured_stream_rates(10.0, 4.0))
        else:
            ap = Px4Autopilot(f"udpin://127.0.0.1:{udp_port}")
            ap.attitude_rate_hz, ap.position_rate_hz = 10.0, 4.0
        try:
            await ap.connect(timeout_s=5.0)
            att_hz, pos_hz = await _rates_seen(ap, 3.0)
        finally:
            await ap.close()
    # 50 and 30 Hz unasked (the sim's dialect defaults and DEFAULT_STREAM_RATES_HZ)
    assert 7.0 <= att_hz <= 13.0, att_hz
    assert 2.5 <= pos_hz <= 5.5, pos_hz


@pytest.mark.parametrize("highres", [True, False])
async def test_raw_imu_is_asked_for_only_where_highres_imu_is_refused(mav, udp_port, highres):
    config = mav.short_config()
    # an autopilot without HIGHRES_IMU (105) answers UNSUPPORTED
    refused = frozenset() if highres else frozenset({105})
    with mav.sim_vehicle(config, "ardupilot", udp_port, unsupported_messages=refused) as sim:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        try:
            await ap.connect(timeout_s=5.0)
            await mav.wait_for(lambda: 33 in sim.streamed_message_ids, 5.0, "the stream requests answered")
            resent = [m for m, _ in ap._streams_to_request() if ap._stream_wanted(m)]
        finally:
            await ap.close()
    assert (105 in sim.streamed_message_ids, 27 in sim.streamed_message_ids) == (highres, not highres)
    assert (27 in resent) == (not highres)  # the re-requests after a silent stream say the same
