"""The fault campaign (companion_lab.fault_campaign): its draws are the seed's alone, the failsafe
is required exactly where a fault outlasts the autopilot's timeout, the figures count the rows;
and a small campaign flown on the MAVLink sim vehicle keeps the safety contract."""

from __future__ import annotations

import json
import math

import pytest

from companion_lab import fault_campaign as fc


def test_the_draws_are_the_seeds_alone_fault_major_and_within_their_ranges():
    a = fc.draw_faults(6, 3, ("stall_3s", "link_cut"))
    assert a == fc.draw_faults(6, 3, ("stall_3s", "link_cut"))
    assert a != fc.draw_faults(6, 4, ("stall_3s", "link_cut"))
    assert [d.fault for d in a] == ["stall_3s"] * 6 + ["link_cut"] * 6
    assert [d.index for d in a] == list(range(12)) and len({d.seed for d in a}) == 12
    assert {d.dialect for d in a} == set(fc.DIALECTS) and {d.moment for d in a} <= set(fc.MOMENTS)
    assert all(fc.HEIGHT_RANGE_M[0] <= d.height_m <= fc.HEIGHT_RANGE_M[1] for d in a)
    assert all(fc.CRUISE_RANGE[0] <= d.fraction <= fc.CRUISE_RANGE[1] for d in a)
    many = fc.draw_faults(40, 1, ("stall_1s",))
    assert {d.moment for d in many} == set(fc.MOMENTS)  # every moment is drawn
    with pytest.raises(ValueError, match="at least one"):
        fc.draw_faults(0, 1, ("stall_1s",))
    with pytest.raises(ValueError, match="unknown fault"):
        fc.draw_faults(1, 1, ("freeze",))


def test_the_fault_list_of_the_command_line():
    assert fc.parse_faults("all") == fc.DEFAULT_FAULTS
    assert fc.parse_faults(" stall_1s, link_cut,stall_1s ") == ("stall_1s", "link_cut")
    for bad in ("", "stall_2s", "stall_1s,flood"):
        with pytest.raises(ValueError, match="unknown fault"):
            fc.parse_faults(bad)


@pytest.mark.parametrize(
    ("fault", "ardupilot", "px4"),
    [
        ("stall_1s", False, False),  # under PX4's 1 s (and the margin), ArduCopter's 5.5 s
        ("stall_3s", False, True),
        ("stall_15s", True, True),
        ("link_cut", True, True),
        ("forged_command", False, False),  # stops nothing of ours
    ],
)
def test_the_failsafe_is_required_where_the_fault_outlasts_the_autopilots_timeout(mav, fault, ardupilot, px4):
    config = mav.short_config()
    got = {
        dialect: fc.failsafe_required(config, fc.FaultDraw(0, 0, fault, dialect, "descent", 5.0, 0.5))
        for dialect in fc.DIALECTS
    }
    assert got == {"ardupilot": ardupilot, "px4": px4}
    assert fc.failsafe_timeout_s(config, "ardupilot", "stall_3s") == 5.0 + config.runtime.loop_stall_s
    assert fc.failsafe_timeout_s(config, "ardupilot", "link_cut") == 5.0
    assert fc.failsafe_timeout_s(config, "px4", "stall_3s") == config.sim.vehicle.offboard_loss_timeout_s


def _row(dialect="px4", required=False, failsafe_s=None, released=None, lost="", fired=True) -> dict:
    return {
        "dialect": dialect,
        "fired": fired,
        "failsafe_required": required,
        "failsafe_s": failsafe_s,
        "released_on_pad": released == "on",
        "released_off_pad": released == "off",
        "lost": lost,
        "touchdown_ne_m": (14.0, 14.0) if lost != "did_not_land" else None,
        "touchdown_speed_m_s": 0.7,
    }


def test_the_figures_count_the_rows_and_name_what_breaks_the_contract():
    rows = [
        _row("px4", True, 1.0),
        _row("ardupilot", True, None),  # a failsafe missed
        _row("ardupilot", False, 0.9),  # one that fired though not required
        _row("px4", released="on"),
        _row("px4", released="off", lost="crashed"),
        _row("px4", fired=False, lost="did_not_land"),
    ]
    s = fc.summarize_faults(rows)
    assert s == {
        "landings": 6,
        "fired": 5,
        "released_off_pad": 1,
        "released_on_pad": 1,
        "failsafe_required": 2,
        "failsafe_reached": 1,
        "failsafe_unrequired": 1,
        "lost": 2,
        "touchdown_speed_max_m_s": 0.7,
        "dialects": {"ardupilot": 2, "px4": 4},
    }
    broken = fc.contract_broken({"summary": {"stall_3s": s}})
    assert broken == [
        "stall_3s: 1 parcel(s) released off the pad",
        "stall_3s: failsafe reached in 1 of 2",
        "stall_3s: 2 vehicle(s) lost",
        "stall_3s: the fault fired in 5 of 6 landings",
    ]
    clean = fc.summarize_faults([_row("px4", True, 1.0), _row("ardupilot", released="on")])
    assert fc.contract_broken({"summary": {"link_cut": clean}}) == []


@pytest.mark.flight
def test_a_small_fault_campaign_keeps_the_safety_contract():
    """One landing per fault on the MAVLink sim vehicle (params/sitl_short.toml), real time: no
    parcel released off the pad, the autopilot's failsafe reached wherever the fault outlasted its
    timeout, no vehicle lost; forged commands all refused and the delivery made as if none came."""
    result = fc.run_fault_campaign(1, 2, ("stall_1s", "stall_15s", "link_cut", "forged_command"))
    rows = [x for ls in result["landings"].values() for x in ls]
    print("\n" + json.dumps(result["summary"], indent=1))
    assert len(rows) == 4 and all(x["fired"] for x in rows), [x["fired_phase"] for x in rows]
    assert fc.contract_broken(result) == []
    for x in rows:
        assert not x["released_off_pad"] and not x["lost"], x
        if x["failsafe_required"]:
            assert x["failsafe_s"] is not None and x["failsafe_s"] <= x["failsafe_timeout_s"] + 1.0, x
        assert math.isfinite(x["touchdown_speed_m_s"]) and x["max_from_home_m"] < 40.0, x
    assert sum(x["failsafe_required"] for x in rows) >= 2  # stall_15s and link_cut, on either dialect
    (forged,) = result["landings"]["forged_command"]
    assert forged["forged_sent"] >= 20 and forged["forged_refused"] == forged["forged_sent"]
    assert forged["released_on_pad"] and forged["failure_kind"] == "none"
    (hang,) = result["landings"]["stall_15s"]
    assert not hang["released"] and hang["failure_kind"] in ("autopilot_landed", "pilot_takeover"), hang
    json.loads(json.dumps(result, default=lambda o: None))  # what the command writes


@pytest.mark.flight
def test_a_3_s_stall_late_in_the_cruise_on_arducopter_releases_nothing_off_the_pad(mav):
    """The campaign's draw that found an off-pad release (seed 1 of `--faults all --n 10`, landing
    14): after a 3 s stall in the cruise (under ArduCopter's 5.5 s failsafe; GUID_TIMEOUT flew the
    last setpoint on, ~11 m past the pad) the resumed GPS-only descent (sitl_short's
    require_pad_lock = false) came down ~2 m off the pad. The mission never releases where its own
    estimate puts the touchdown outside the pad: it flies home with the parcel."""
    config = mav.short_config(return_home=False)
    row = fc.fly_fault_landing(config, fc.FaultDraw(13, 1013, "stall_3s", "ardupilot", "cruise", 6.8, 0.69))
    assert row["fired"] and not row["lost"], row
    assert not row["released_off_pad"], (row["touchdown_ne_m"], row["failure_kind"])
