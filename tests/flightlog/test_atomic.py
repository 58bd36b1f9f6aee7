"""Result files written whole or not at all, and the room a run keeps for them, on a real full
disk (a tmpfs mounted for the test)."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from companion.flightlog.atomic import ROOM_BYTES, ROOM_FILE, Room, write_text_atomic

from ..tmpfs import fill, mounted_tmpfs


def _free(folder: Path) -> int:
    st = os.statvfs(folder)
    return st.f_bavail * st.f_frsize


def test_a_summary_on_a_full_disk_keeps_the_previous_one(tmp_path: Path):
    with mounted_tmpfs(tmp_path / "disk", "1m") as d:
        f = d / "summary.json"
        write_text_atomic(f, '{"delivered": true}')
        fill(d)
        with pytest.raises(OSError) as err:
            write_text_atomic(f, '{"delivered": false, "padding": "' + "x" * 65536 + '"}')
        assert err.value.errno == errno.ENOSPC
        assert f.read_text() == '{"delivered": true}'  # the previous state, whole
        assert sorted(p.name for p in d.iterdir()) == ["ballast", "summary.json"]  # no temporary left


def test_a_summary_is_replaced_whole(tmp_path: Path):
    f = tmp_path / "summary.json"
    write_text_atomic(f, "first")
    write_text_atomic(f, "second", sync=False)
    assert f.read_text() == "second" and sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]


def test_the_room_is_real_space_given_back_for_the_last_files(tmp_path: Path):
    with mounted_tmpfs(tmp_path / "disk", "1m") as d:
        before = _free(d)
        room = Room(d)
        assert room.held and (d / ROOM_FILE).stat().st_size == ROOM_BYTES
        assert before - _free(d) >= ROOM_BYTES  # allocated, not a sparse file
        fill(d)
        with pytest.raises(OSError):
            write_text_atomic(d / "run.json", "{}" * 1000)
        room.release()
        write_text_atomic(d / "run.json", "{}" * 1000)  # fits now
        assert not (d / ROOM_FILE).exists()
        room.release()  # idempotent


def test_no_room_on_a_full_disk_leaves_nothing_behind(tmp_path: Path, caplog):
    with mounted_tmpfs(tmp_path / "disk", "1m") as d:
        fill(d)
        room = Room(d)
        assert not room.held and not (d / ROOM_FILE).exists()
        assert "cannot keep room for the run's last files" in caplog.text
