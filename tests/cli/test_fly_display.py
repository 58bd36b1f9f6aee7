"""What `companion fly` shows at the end of a returned flight: distances to home measured from
where the outbound started, which the return flies to, not from the autopilot's home, which
ArduCopter and PX4 move to where they arm (the pad, for the way back)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from companion.autopilot.types import HomePosition
from companion.cli.fly_display import distance_to_go_m, progress_fields, summary_rows
from companion.delivery.mission import MissionSummary
from companion.estimation.types import StateEstimate

PAD = (20.0, 28.0, 0.0)  # 34.4 m from where the outbound started


def _shell(summary: MissionSummary, at: tuple[float, float], returning: bool) -> SimpleNamespace:
    """A shell at the end of a delivery whose autopilot re-armed on the pad (its home there now)."""
    est = StateEstimate(0.0, at[0], at[1], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    mission = SimpleNamespace(pad_ned=np.array(PAD), summary=summary, returning=returning, start_ned=np.zeros(3))
    home_on_pad = HomePosition(0.0, -19.8, -43.9, 850.0, PAD[0], PAD[1], 0.0)
    stats = SimpleNamespace(setpoints_sent=1, setpoints_clamped=0, requests=1, requests_failed=0)
    return SimpleNamespace(
        mission=mission,
        estimate=est,
        autopilot=SimpleNamespace(telemetry=SimpleNamespace(home=home_on_pad)),
        stats=stats,
        events=[],
        ground_commands=[],
        made_ready=[],
    )


def test_at_the_end_of_a_returned_flight_nothing_is_left_to_go_and_home_is_where_it_started():
    s = MissionSummary(delivered=True, returned=True, pad_touchdown_ned=(20.03, 28.0, 0.0))
    s.home_touchdown_ned = (0.04, -0.03, 0.0)
    shell = _shell(s, (0.04, -0.03), returning=True)
    assert distance_to_go_m(shell) == pytest.approx(0.05)
    where = progress_fields(shell, SimpleNamespace(phase=SimpleNamespace(value="done"), sector=0))["where"]
    assert where.startswith("50 mm to go"), where  # it said "34.41 m to go" (to the autopilot's home)
    rows = dict(summary_rows(s, shell, "runs/x"))
    assert rows["touchdown from home (estimate)"] == "50 mm", rows
    assert rows["touchdown from the configured pad (estimate)"] == "30 mm", rows


def test_on_the_way_out_the_pad_is_what_is_left_to_go():
    shell = _shell(MissionSummary(), (0.0, 0.0), returning=False)
    assert distance_to_go_m(shell) == pytest.approx(float(np.hypot(PAD[0], PAD[1])))
