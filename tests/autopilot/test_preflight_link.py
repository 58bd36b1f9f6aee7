"""The pre-flight link budget: a serial line's bytes each way against what it carries (8N1), one
row, none on UDP/TCP; the backends say which line they run on."""

from __future__ import annotations

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.preflight.link import (
    LINK_WARN_SHARE,
    LINK_WRONG_SHARE,
    LinkProbe,
    check_link_budget,
    predicted_uplink_bytes_s,
)
from companion.autopilot.preflight.report import Requirements, Status
from companion.autopilot.preflight.runner import run_checks
from companion.autopilot.px4 import Px4Autopilot

AP = Requirements("ardupilot", setpoint_rate_hz=20.0, link_loss_resume_modes=("hold",))


def test_no_row_without_a_serial_line():
    assert check_link_budget(AP, None) == []
    assert check_link_budget(AP, LinkProbe(None, 9000.0, 1500.0, 2.0)) == []


@pytest.mark.parametrize(
    ("down_share", "status"),
    [(0.1, Status.OK), (LINK_WARN_SHARE + 0.01, Status.WARN), (LINK_WRONG_SHARE + 0.01, Status.WRONG)],
)
def test_the_worse_direction_decides(down_share, status):
    line = 921600 / 10
    (row,) = check_link_budget(AP, LinkProbe(921600, down_share * line, 0.02 * line, 2.0))
    assert row.status is status and row.value == "921600 baud = 92160 B/s each way"
    assert f"{100 * down_share:.1f} %, measured" in row.detail
    if status is not Status.OK:
        assert "serial_115200.toml" in row.detail  # what to do about it
    (up_row,) = check_link_budget(AP, LinkProbe(921600, 0.02 * line, down_share * line, 2.0))
    assert up_row.status is status
    assert f"{down_share * line:.0f} B/s measured before it" in up_row.detail


def test_the_uplink_counts_the_setpoint_stream_the_check_runs_before():
    (row,) = check_link_budget(AP, LinkProbe(115200, 1000.0, 300.0, 2.0))
    assert f"up {predicted_uplink_bytes_s(AP):.0f} B/s" in row.detail and "300 B/s measured before it" in row.detail


def test_without_byte_counts_the_uplink_is_predicted_from_the_setpoint_rate():
    (row,) = check_link_budget(AP, LinkProbe(115200))
    up = predicted_uplink_bytes_s(AP)
    assert up == 20.0 * 65 + 2 * 21  # 20 Hz SET_POSITION_TARGET_LOCAL_NED and two heartbeats
    assert row.status is Status.OK and "predicted from runtime.setpoint_rate_hz" in row.detail
    assert "down not counted" in row.detail
    fast = Requirements("px4", setpoint_rate_hz=200.0, link_loss_resume_modes=("hold",))
    (slow_line,) = check_link_budget(fast, LinkProbe(57600))  # 13.0 kB/s of setpoints on 5.76 kB/s
    assert slow_line.status is Status.WRONG


def test_a_wrong_budget_fails_the_check():
    report = run_checks(AP, {}, link=LinkProbe(57600, 5700.0, 600.0, 2.0))
    assert any(c.name == "link budget" for c in report.wrong)
    assert not report.passed


@pytest.mark.parametrize(
    ("url", "baud"),
    [
        ("serial:///dev/ttyAMA0:921600", 921600),
        ("/dev/ttyUSB0:115200", 115200),
        ("udpin:0.0.0.0:14550", None),
        ("tcp:127.0.0.1:5760", None),
    ],
)
def test_the_ardupilot_backend_names_its_line(url, baud):
    t = ArduPilotAutopilot(url).link_traffic()
    assert t.baud == baud and t.rx_bytes is None  # not connected: nothing counted yet


@pytest.mark.parametrize(
    ("url", "baud"),
    [("serial:///dev/ttyAMA0:921600", 921600), ("serial:///dev/ttyAMA0", None), ("udpin://0.0.0.0:14540", None)],
)
def test_the_px4_backend_names_its_line(url, baud):
    t = Px4Autopilot(url).link_traffic()
    assert t.baud == baud and t.rx_bytes is None and t.tx_bytes is None


async def test_the_ardupilot_backend_counts_the_bytes_it_receives_and_sends(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port):
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        await ap.connect(timeout_s=3.0)
        t0 = ap.link_traffic()
        n0 = ap.counters.messages
        await mav.wait_for(lambda: ap.counters.messages > n0 + 50, 5.0, "telemetry")
        t1 = ap.link_traffic()
        await ap.close()
    assert t1.rx_bytes is not None and t0.rx_bytes is not None and t1.tx_bytes is not None
    assert t1.rx_bytes - t0.rx_bytes >= 50 * 12  # at least a MAVLink 2 frame's overhead per message
    assert t1.tx_bytes > 0  # our heartbeats and stream requests
