"""[telemetry] zenoh_config names a file or a shipped parameter set; neither is said as both, the
path first (it was reported as "no shipped parameter set of that name" only)."""

from __future__ import annotations

import pytest

from companion.config import ConfigError, load_config, shipped_params_path
from companion.delivery.telemetry import zenoh_settings_from_config


def _cfg(ref: str):  # type: ignore[no-untyped-def]
    return load_config(shipped_params_path("sitl_short.toml"), overrides={"telemetry": {"zenoh_config": ref}})


def test_a_missing_zenoh_file_is_named_with_its_path(tmp_path):
    missing = tmp_path / "site" / "zenoh.toml"
    with pytest.raises(ConfigError) as err:
        zenoh_settings_from_config(_cfg(str(missing)))
    text = "; ".join(err.value.problems)
    assert err.value.source == "telemetry.zenoh_config" and f"no file {missing}" in text, text
    assert "and no shipped parameter set of that name" in text, text


def test_a_path_and_a_shipped_name_both_load(tmp_path):
    own = tmp_path / "z.toml"
    own.write_text(shipped_params_path("zenoh_loopback.toml").read_text())
    assert zenoh_settings_from_config(_cfg(str(own))) == zenoh_settings_from_config(_cfg("zenoh_loopback.toml"))
