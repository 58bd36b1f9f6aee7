"""Real small or read-only file systems for the storage-fault tests: a tmpfs mounted for the test
(root only; a test is skipped with the reason where mounting is not permitted), unmounted after."""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


@contextmanager
def mounted_tmpfs(where: Path, size: str, read_only: bool = False) -> Iterator[Path]:
    """A tmpfs of ``size`` (``2m``) mounted on ``where`` (created) for the block, then unmounted;
    ``read_only``: mounted ``ro`` (chmod 0555 does not stop root). Skips the test when it cannot
    be mounted (not root, no mount permission in the container)."""
    mount = shutil.which("mount")
    if mount is None or os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root and mount(8)")
    where.mkdir(parents=True, exist_ok=True)
    opts = f"{'ro,' if read_only else ''}size={size}"
    done = subprocess.run([mount, "-t", "tmpfs", "-o", opts, "tmpfs", str(where)], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip() or done.returncode}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False, capture_output=True)


def fill(folder: Path, leave_bytes: int = 0) -> None:
    """Fill ``folder``'s file system until at most ``leave_bytes`` are free (a file ``ballast``)."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    with (folder / "ballast").open("wb", buffering=0) as fh:
        chunk = b"\0" * 65536
        left = max(0, free - leave_bytes)
        try:
            while left > 0:
                left -= fh.write(chunk[: min(len(chunk), left)])
        except OSError:
            pass  # full
