"""The UWB fusion path with four anchors at one height (params/uwb_anchors_one_height.toml): fixes
carry the weak vertical (VDOP) into the EKF, and a UWB-only landing still lands on the pad."""

from __future__ import annotations

from typing import Any

from companion.autopilot.types import LandedState
from companion.config import shipped_params_path
from companion.events import Phase
from companion_lab.demo import run_demo
from companion_sitl.params import load_simulated_config


def test_uwb_only_landing_with_anchors_at_one_height() -> None:
    config = load_simulated_config(
        shipped_params_path("delivery_paper.toml"),
        overrides={
            "sim": {"seed": 3, "gps_bias_m": (2.0, 0.0, 0.0), "pad_offset_m": (0.4, -0.6)},
            "landing": {"use_camera": False, "uwb_anchors": "uwb_anchors_one_height.toml"},
        },
    )
    seen: dict[str, Any] = {}

    def tick(shell: Any, out: Any) -> None:
        if shell.fusion is not None:
            seen["fusion"] = shell.fusion
            seen["multi"] = shell.landing.multilaterator
            st = shell.autopilot.telemetry.status
            now = shell.now()
            if (
                out.phase in (Phase.OUTBOUND, Phase.LANDING_PAD)
                and st is not None
                and st.landed is not LandedState.ON_GROUND
            ):
                seen.setdefault("snapshots", []).append((now, dict(shell.fusion.counters.outcomes)))
            elif out.phase is Phase.LANDING_PAD and "touchdown_s" not in seen:
                seen["touchdown_s"] = now  # the land detector's ON_GROUND

    r = run_demo(config, on_tick=tick)
    assert r.delivered and r.returned, r.failure
    assert r.pad_landing_error_m < 0.1  # GPS-only lands ~2 m off with this bias (test_delivery_sim)
    fusion, multi = seen["fusion"], seen["multi"]
    assert multi.layout.coplanar
    assert fusion.counters.uwb_used > 100
    # in the air the larger vertical variance keeps honest fixes inside the gate. In the last second
    # (touchdown, then the land detector's wait), at the anchors' height (VDOP > 2) and with the
    # vehicle stopped on the ground, the EKF rejects some, which no longer steer the landing
    airborne = [c for t, c in seen["snapshots"] if t < seen["touchdown_s"] - 1.0][-1]
    accepted = airborne.get("uwb.accepted", 0)
    gated = airborne.get("uwb.rejected_gate", 0)
    assert accepted > 50 and gated < 0.05 * accepted, airborne
