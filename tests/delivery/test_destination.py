"""A destination from an order or the autopilot's mission becomes a validated configuration."""

from __future__ import annotations

import math

import pytest

from companion.config import load_config, shipped_params_path
from companion.delivery.destination import Destination, DestinationError, GeoPad, config_for_destination


@pytest.fixture
def config():  # type: ignore[no-untyped-def]
    return load_config(shipped_params_path("px4_sih_quad.toml"))


def test_pad_and_alternate_replace_the_configured_pad(config) -> None:  # type: ignore[no-untyped-def]
    dest = Destination(GeoPad(47.3985, 8.5465), "order 7", alternate=GeoPad(47.3990, 8.5470, 488.5))
    out = config_for_destination(config, dest)
    assert (out.mission.pad.lat_deg, out.mission.pad.lon_deg, out.mission.pad.alt_amsl_m) == (47.3985, 8.5465, None)
    assert out.mission.pad.north_m is None and out.mission.pad.size_m == config.mission.pad.size_m
    assert out.mission.alternate_pad is not None and out.mission.alternate_pad.alt_amsl_m == 488.5
    assert config.mission.alternate_pad is None  # the original is untouched
    assert out.mission.height_m == config.mission.height_m  # everything else as configured


@pytest.mark.parametrize(
    ("pad", "words"),
    [
        (GeoPad(math.nan, 8.5), "pad.lat_deg = nan"),
        (GeoPad(47.0, 181.0), "pad.lon_deg = 181.0"),
        (GeoPad(47.0, 8.5, math.inf), "pad.alt_amsl_m = inf"),
        (GeoPad("47", 8.5), "expected a number"),  # type: ignore[arg-type]
    ],
)
def test_bad_coordinates_are_refused_by_name(config, pad: GeoPad, words: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(DestinationError, match=words.replace(".", r"\.")):
        config_for_destination(config, Destination(pad, "order 1"))


def test_a_pad_outside_the_fence_is_refused_as_the_file_would_be(config) -> None:  # type: ignore[no-untyped-def]
    data = config.model_dump()
    data["fence"] = {
        "enabled": True,
        "inclusion": [{"vertices_deg": [[47.39, 8.54], [47.39, 8.55], [47.40, 8.55], [47.40, 8.54]]}],
    }
    from companion.config import config_from_dict

    fenced = config_from_dict(data, "fenced")
    assert config_for_destination(fenced, Destination(GeoPad(47.395, 8.545), "inside")).mission.pad.lat_deg == 47.395
    with pytest.raises(DestinationError, match=r"mission\.pad"):
        config_for_destination(fenced, Destination(GeoPad(47.45, 8.545), "outside"))
