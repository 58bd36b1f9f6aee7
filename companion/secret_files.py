"""Files holding a secret (the MAVLink signing key, the ground-command HMAC secret, a Zenoh
password): read only when no account but the owner can read or write them.

A secret others can read is no secret; one others can write lets them swap in their own key. So
such a file is refused at start-up with :class:`SecretFileExposed`, which names the file, its
mode and the fix (``chmod 600 FILE``), before anything is flown or opened.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from companion.config import CompanionConfig

#: group and world read and write bits: any of them set exposes the secret to another account
EXPOSING_BITS = stat.S_IRGRP | stat.S_IWGRP | stat.S_IROTH | stat.S_IWOTH


class SecretFileExposed(ValueError):
    """A secret file whose group or world can read or write it: ``path``, ``mode`` (permission
    bits) and, in the message, the ``chmod 600`` that fixes it."""

    def __init__(self, what: str, path: Path, mode: int) -> None:
        self.path = path
        self.mode = mode
        access = []
        for who, read, write in (("group", stat.S_IRGRP, stat.S_IWGRP), ("others", stat.S_IROTH, stat.S_IWOTH)):
            can = " and ".join(verb for verb, bit in (("read", read), ("write", write)) if mode & bit)
            if can:
                access.append(f"{who} can {can} it")
        super().__init__(
            f"{what} {path}: mode {mode:04o}: {', '.join(access)}; a secret must be its owner's only: "
            f"run `chmod 600 {path}`"
        )


def check_private_mode(path: str | Path, mode: int, what: str) -> None:
    """:class:`SecretFileExposed` when ``mode`` (an ``st_mode``) gives group or others read or
    write access to the secret file ``path``."""
    bits = stat.S_IMODE(mode)
    if bits & EXPOSING_BITS:
        raise SecretFileExposed(what, Path(path), bits)


def read_private(path: str | Path, what: str) -> bytes:
    """The bytes of the secret file ``path`` (``what`` names it in errors), refused with
    :class:`SecretFileExposed` when group or others may read or write it. The mode is that of the
    file opened (``fstat``), so the check and the read see the same file. Other failures are the
    ``OSError`` of opening or reading it (not found, a directory, no permission)."""
    with Path(path).open("rb") as fh:
        check_private_mode(path, os.fstat(fh.fileno()).st_mode, what)
        return fh.read()


def exposed_secret(path: str | Path, what: str) -> SecretFileExposed | None:
    """The :class:`SecretFileExposed` the file ``path`` would be refused with, or None (also when
    it cannot be looked at: reading it then names that failure)."""
    try:
        check_private_mode(path, os.stat(path).st_mode, what)
    except SecretFileExposed as err:
        return err
    except OSError:
        return None
    return None


def configured_secret_files(config: CompanionConfig) -> list[tuple[str, str, str]]:
    """(parameter key, what the file is, path) of each secret file the configuration will read:
    the MAVLink signing key (with signing on) and the ground-command secret (with commands on)."""
    out = []
    if config.signing.enabled and config.signing.key_file:
        out.append(("signing.key_file", "signing key file", config.signing.key_file))
    commands = config.telemetry.commands
    if commands.enabled and commands.secret_file:
        out.append(("telemetry.commands.secret_file", "ground-command secret file", commands.secret_file))
    return out
