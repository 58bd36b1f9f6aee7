"""companion bench vision --ambiguity / --range: the attitude rule on a rendered approach, the
detection range search."""

from __future__ import annotations

import pytest

from companion.cli.bench import format_ambiguity_result, format_range_result
from companion.vision.camera import load_default_camera
from companion_lab.bench.vision import bench_ambiguity, bench_vision_range, camera_720p


def test_attitude_fuses_more_of_a_rendered_approach_and_none_wrong() -> None:
    r = bench_ambiguity(n_frames=150, seed=0)
    before, after = r["before"], r["after"]
    assert before["detections"] >= 140 and after["detections"] >= 140
    assert before["ambiguous"] > 0  # the sequence does contain unresolved mirror pairs
    assert after["fused_share"] > before["fused_share"]
    assert r["extra_fused"] == after["fused"] - before["fused"] > 0
    # nothing fused after is the mirror solution, and its error against truth stays bounded
    assert after["fused_wrong_choice"] == 0
    assert after["fused_rotation_error_max_deg"] < 10.0
    assert after["fused_position_error_max_m"] < 0.5
    assert after["fused_camera_position_error_max_m"] < before["fused_camera_position_error_max_m"]
    text = format_ambiguity_result("t", r)
    assert "fused_share" in text and "resolved by (after)" in text and f"{r['extra_fused']:+d}" in text


def test_bench_ambiguity_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="n_frames"):
        bench_ambiguity(n_frames=1)
    with pytest.raises(ValueError, match="attitude_noise_deg"):
        bench_ambiguity(n_frames=10, attitude_noise_deg=float("nan"))


def test_camera_720p_is_the_same_lens() -> None:
    cam = load_default_camera()
    big = camera_720p(cam)
    assert big.size == (1280, 720)
    assert big.fx == pytest.approx(2 * cam.fx) and big.cy == pytest.approx(359.5)


def test_range_search_structure_and_order() -> None:
    r = bench_vision_range(5, seed=3, heights_m=[2.0, 10.0, 30.0], tilts_deg=(0.0,))
    runs = {x["resolution"]: x for x in r["runs"]}
    assert set(runs) == {"640x480", "1280x720"}
    for x in runs.values():
        assert x["detection_rates"][0]["height_m"] == 2.0
        assert all(0.0 <= row[m] <= 1.0 for row in x["detection_rates"] for m in ("outer", "inner"))
    # the larger image sees the outer marker at least as high
    assert runs["640x480"]["outer_range_m"] is not None
    assert runs["1280x720"]["outer_range_m"] >= runs["640x480"]["outer_range_m"]
    assert "1280x720" in format_range_result(r)
    with pytest.raises(ValueError, match="heights_m"):
        bench_vision_range(5, heights_m=[3.0, 2.0])
    with pytest.raises(ValueError, match="frames_per_height"):
        bench_vision_range(2)
