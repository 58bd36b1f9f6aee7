"""A recording's frame-times CSV (``frame,time_s``) as bytes.

Rule: the times are read (one per row, in order, finite and increasing) or refused with
CameraFileError naming the file; never another exception."""

from __future__ import annotations

import itertools
import math

import pytest

from companion.flightlog.camera_file import CameraFileError, load_frame_times

from . import harness

pytestmark = pytest.mark.fuzz

SEEDS = [
    b"frame,time_s\n0,0.0\n1,0.033\n2,0.066\n",
    b"frame,time_s\r\n0,12.5\r\n1,12.533333333333333\r\n2,12.566666666666666\r\n3,12.6\r\n",
    b"frame, time_s\n0,1\n\n1,2\n",
]
NASTY = [
    b"",
    b"\n",
    b"frame,time_s",
    b"\xff\xfeframe,time_s\n0,0\n",
    b"\xef\xbb\xbfframe,time_s\n0,0\n",
    b"frame,time_s\n0,0\x00\n",
    b"frame,time_s\n0,nan\n",
    b"frame,time_s\n0,inf\n",
    b"frame,time_s\n0,1\n1,1\n",
    b"frame,time_s\n1,0\n",
    b'frame,time_s\n0,"' + b"1" * 200000 + b'"\n',
    b'frame,time_s\n0,"0\n1,1\n',
    b"frame,time_s\n0,0.0\n1,0.0" + b"3" * 5000 + b"\n",
    b"frame,time_s\n" + b"9" * 5000 + b",0\n",
]


def test_camera_times_csv(tmp_path, fuzz_budget) -> None:
    n = itertools.count()

    def feed(data: bytes) -> str:
        p = tmp_path / f"t{next(n)}.csv"
        p.write_bytes(data)
        try:
            times = load_frame_times(p)
        except CameraFileError as err:
            assert str(p) in str(err), f"the error does not name the file: {err}"
            raise
        assert times and all(math.isfinite(t) for t in times)
        assert all(b > a for a, b in itertools.pairwise(times))
        return "read"

    allowed = (CameraFileError,)
    for data in SEEDS + NASTY:
        harness.check("camera times csv", feed, data, allowed)
    harness.run(
        harness.fuzz_bytes(SEEDS + NASTY),
        lambda d: harness.check("camera times csv", feed, d, allowed),
        fuzz_budget,
    )
