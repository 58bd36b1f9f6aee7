"""Delivery after delivery (docs/flying.md): against one PX4 sim vehicle that is never restarted,
`companion fly` twice, as an operator would; each mission leaves PX4 in HOLD, where the next arms
(PX4 reports itself not armable disarmed in OFFBOARD without setpoints, the mode a companion-flown
landing leaves). Without that, the next mission's pre-flight wait says why it cannot arm instead of
waiting silently. `fly` shows the phase, distance to go and progress, then the summary table."""

from __future__ import annotations

import subprocess
import sys

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.types import FlightMode
from companion.cli import exits
from companion.config import shipped_params_path

pytestmark = pytest.mark.flight


def _fly_params(tmp_path, port: int):
    text = shipped_params_path("sitl_short.toml").read_text()
    text = text.replace('autopilot = "sim"', 'autopilot = "px4"')
    text = text.replace('connection = "udpin://0.0.0.0:14540"', f'connection = "udpin://127.0.0.1:{port}"')
    f = tmp_path / "vehicle.toml"
    text += "\n[landing]\nfusion = false\nuse_camera = false\nuse_uwb = false\n[telemetry]\nenabled = false\n"
    f.write_text(text)
    return f


def test_fly_twice_on_the_same_px4(mav, udp_port, tmp_path):
    config = mav.short_config()
    params = _fly_params(tmp_path, udp_port)

    def extra(run: int) -> list[str]:
        return ["--out", str(tmp_path / f"run{run}"), "--timeout", "120"]

    with mav.sim_vehicle(config, "px4", udp_port) as sim:
        outs = []
        for run in (1, 2):
            proc = subprocess.run(
                [sys.executable, "-m", "companion", "fly", "--params", str(params), "--no-preflight", *extra(run)],
                capture_output=True,
                text=True,
                timeout=180,
                cwd=tmp_path,
            )
            assert proc.returncode == exits.OK, (run, proc.stdout[-2000:], proc.stderr[-3000:])
            outs.append(proc.stdout)
            assert sim.vehicle.mode is FlightMode.HOLD and not sim.vehicle.armed  # where the next one arms
        assert len(sim.vehicle.touchdowns) == 4
    for out in outs:
        assert "DELIVERED, returned home" in out, out[-2000:]
        for row in ("flight time", "touchdown from the configured pad (estimate)", "touchdown from home (estimate)"):
            assert row in out
        assert "autopilot mode for the next mission" in out and "switched to HOLD" in out
        assert "landing_home" in out or "done" in out  # the progress line's last phase, when not a terminal


async def test_left_in_offboard_the_next_mission_says_why_it_cannot_arm(mav, udp_port, monkeypatch):
    """The old behaviour (no HOLD after the mission): the second mission cannot arm, and its
    failure names PX4's mode rather than only "not healthy"."""
    config = mav.short_config(ready_timeout_s=6.0)

    async def nothing(self):
        return None

    monkeypatch.setattr(Px4Autopilot, "make_ready", nothing)
    with mav.sim_vehicle(config, "px4", udp_port) as sim:
        shell, s = await mav.fly(config, Px4Autopilot(f"udpin://127.0.0.1:{udp_port}"))
        assert s.delivered and s.returned, s.failure
        assert sim.vehicle.mode is FlightMode.OFFBOARD and not sim.vehicle.armed
        shell, s = await mav.fly(config, Px4Autopilot(f"udpin://127.0.0.1:{udp_port}"))
    assert not s.delivered and s.failure.startswith("vehicle not ready after 6.0 s: not healthy"), s.failure
    assert "PX4 health: not armable" in s.failure and "mode offboard (PX4 arms in HOLD)" in s.failure, s.failure
    assert shell.stats.requests == 0  # nothing was commanded
