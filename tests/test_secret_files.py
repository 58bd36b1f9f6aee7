"""Secret files are read only when no account but the owner can read or write them: the error
names the file, its mode, who can do what, and the ``chmod 600`` that fixes it."""

from __future__ import annotations

import itertools

import pytest

from companion.config import config_from_dict
from companion.secret_files import (
    SecretFileExposed,
    configured_secret_files,
    exposed_secret,
    read_private,
)
from companion.telemetry.auth import CommandSettings

SECRET = b"a-shared-secret-0123456789"


def _secret(tmp_path, mode: int):  # type: ignore[no-untyped-def]
    p = tmp_path / "secret"
    p.write_bytes(SECRET + b"\n")
    p.chmod(mode)
    return p


@pytest.mark.parametrize(
    ("mode", "access"),
    [
        (0o640, "group can read it"),
        (0o620, "group can write it"),
        (0o660, "group can read and write it"),
        (0o604, "others can read it"),
        (0o602, "others can write it"),
        (0o644, "group can read it, others can read it"),
        (0o666, "group can read and write it, others can read and write it"),
    ],
)
def test_group_or_world_access_is_refused_naming_file_mode_and_fix(tmp_path, mode: int, access: str) -> None:  # type: ignore[no-untyped-def]
    p = _secret(tmp_path, mode)
    with pytest.raises(SecretFileExposed) as err:
        read_private(p, "test secret")
    assert str(err.value) == (
        f"test secret {p}: mode {mode:04o}: {access}; a secret must be its owner's only: run `chmod 600 {p}`"
    )
    assert err.value.path == p and err.value.mode == mode
    assert isinstance(err.value, ValueError)  # the loaders' callers turn a ValueError into a ConfigError
    exposed = exposed_secret(p, "test secret")
    assert exposed is not None and str(exposed) == str(err.value)


def test_every_mode_without_group_or_world_read_or_write_is_read(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p = _secret(tmp_path, 0o600)
    for owner, group_x, other_x in itertools.product(range(4, 8), (0, 1), (0, 1)):
        mode = owner << 6 | group_x << 3 | other_x
        p.chmod(mode)
        assert read_private(p, "test secret") == SECRET + b"\n", oct(mode)
        assert exposed_secret(p, "test secret") is None


def test_a_missing_file_is_the_readers_oserror_not_an_exposure(tmp_path) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(FileNotFoundError):
        read_private(tmp_path / "nope", "test secret")
    assert exposed_secret(tmp_path / "nope", "test secret") is None


def test_the_ground_command_secret_is_refused_when_others_can_read_it(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p = _secret(tmp_path, 0o644)
    with pytest.raises(SecretFileExposed, match=r"^ground-command secret file .*: mode 0644: .*chmod 600"):
        CommandSettings.read_secret(p)
    p.chmod(0o600)
    assert CommandSettings.read_secret(p) == SECRET


def test_the_configuration_names_each_secret_it_will_read() -> None:
    assert configured_secret_files(config_from_dict({})) == []
    cfg = config_from_dict(
        {
            "autopilot": "ardupilot",
            "signing": {"enabled": True, "key_file": "link.key"},
            "telemetry": {"commands": {"enabled": True, "secret_file": "cmd.secret"}},
        }
    )
    assert configured_secret_files(cfg) == [
        ("signing.key_file", "signing key file", "link.key"),
        ("telemetry.commands.secret_file", "ground-command secret file", "cmd.secret"),
    ]
    off = config_from_dict({"signing": {"key_file": "link.key"}, "telemetry": {"commands": {"secret_file": "s"}}})
    assert configured_secret_files(off) == []  # not read while off
