"""The UWB fusion path with four anchors at one height (params/uwb_anchors_one_height.toml): fixes
carry the weak vertical (VDOP) into the EKF, and a UWB-only landing still lands on the pad."""

from __future__ import annotations

from typing import Any

from companion.config import load_config, shipped_params_path
from companion_sitl.demo import run_demo


def test_uwb_only_landing_with_anchors_at_one_height() -> None:
    config = load_config(
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

    r = run_demo(config, on_tick=tick)
    assert r.delivered and r.returned, r.failure
    assert r.pad_landing_error_m < 0.1  # GPS-only lands ~2 m off with this bias (test_delivery_sim)
    fusion, multi = seen["fusion"], seen["multi"]
    assert multi.layout.coplanar
    assert fusion.counters.uwb_used > 100
    accepted = fusion.counters.outcomes.get("uwb.accepted", 0)
    gated = fusion.counters.outcomes.get("uwb.rejected_gate", 0)
    assert gated < 0.05 * accepted  # the larger vertical variance keeps honest fixes inside the gate
