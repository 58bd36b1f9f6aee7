"""The flight logs' bytes: batching the writes (one shared writer thread, ``writerows`` per
period) changed nothing in the files.

``DIGESTS`` are the SHA-256 of every CSV of the short seeded flight (GPS-only and fused). They
were first taken from the per-file-thread, row-by-row writer this replaced (commit 0eb72bd), on a
machine whose OpenBLAS ran its SkylakeX kernels; the batched writer gives exactly those bytes
with ``OPENBLAS_CORETYPE=SkylakeX`` (checked). They are now taken with the CPU-dependent
arithmetic pinned (``PINNED_CPU_ENV``, below), so they hold on any x86-64 machine. They pin the
flight as well as the format: regenerate them when the flight itself is meant to change."""

from __future__ import annotations

import csv
import io
import json
import os
import platform
import subprocess
import sys

import numpy as np
import pytest

from companion.flightlog.csvlog import CsvLog

DIGESTS = {
    # fusion=False
    (False, "ap_attitude.csv"): "a96b4580d16f147aa439c24a4d9b45d93016e3aa2bf6abebe528884b2fdd75a4",
    (False, "ap_global.csv"): "a5da1d3022734606fe426f80d7dba0a24bb78d327b263be2d5cffcfae29c4e41",
    (False, "ap_gps.csv"): "e5dd1511370d1a3b5431bdb8387f0709a87b7cebd60bfc350bbf640cc1537984",
    (False, "ap_home.csv"): "4df982460caa067abef55903d407b7b6dbe7d61b032b6fbbc19a35619ae4f791",
    (False, "ap_imu.csv"): "4b19177fe05fb59818b5d947ed4583592ebcb559af571a4ba3edf9f078d2f90f",
    (False, "ap_position.csv"): "203044dae0024c3d4521d71dfc52260b837f5c4f63022072f91665be769f17ca",
    (False, "ap_status.csv"): "00c146201fff84bc0cda9b03c5686aa2e075235f3c296f3c3fdc4a45ebe98a0f",
    (False, "ap_statustext.csv"): "c9b3d025dfe788f58018ca6c5138ee935b2228c3be63c9477257622d1d841c34",
    (False, "camera.csv"): "9a9d9425fde96b314d000395aa96c61b9ceb5f28e74d091fb58baef261322151",
    (False, "commands.csv"): "c85312b82eb8786586a3f8f997838f7a380c4c16f1e1e15fec4db07ff01882d4",
    (False, "ekf.csv"): "3c0ef73fbb26fa9ca884d887b9f91714a1668341ca51d0e90a57f1ee75b6b642",
    (False, "events.csv"): "81fb7901d1f708be1b228e1dac0294be35b2352aa7f53a43421cf14d0dee42f4",
    (False, "flight.csv"): "549fc9b12a23338efff297737ddabc2a4c739cb96d5ab884257f17c7fb3a09ef",
    (False, "guidance.csv"): "562f8ed889017ca7268817cecba8f1a956cc4ee5be52306a4c8177281b417135",
    (False, "requests.csv"): "0dd79ac15e7839c6ee094776d5f30b98ba14709c02dc6f263ee053faa2d3db5f",
    (False, "setpoints.csv"): "1ad3ab79161598ae1ea3a5d4cd4159b58d99de6c8a1b4cac7ba4b33219244e1a",
    (False, "truth.csv"): "3119382ac8b67da53cd801977ac4ddc0aa578d08cfeb401514dad7825c7fac3c",
    (False, "uwb.csv"): "62b0204d2e49c8897570c237edf5dd971352b68222ae184b1c3284ba00637532",
    # fusion=True
    (True, "ap_attitude.csv"): "3d7df6689de67258cd04b4044315e3061a478d92a43e4b4e088c4538b5d1a579",
    (True, "ap_global.csv"): "5f8636c40ebb7c9ea11352476586cc304ba858047d9f2dd74136555b8adf425e",
    (True, "ap_gps.csv"): "dd60b4c8f49d07976ff20c665c2f115534c9a8f563fbbc8072d7e61bbd125e14",
    (True, "ap_home.csv"): "1bd5f70e1535d50e0a967ec51452a17bb538805f292f67a0f48c174ffd5f48f7",
    (True, "ap_imu.csv"): "d98bed6acb7127173446c90105bb653655fe2600ffe5b723ba484b6e1a637f72",
    (True, "ap_position.csv"): "a5a1c9ed39dad16810cfd9653feacc2fe11232e24332d73e4fcef659e7d65570",
    (True, "ap_status.csv"): "8d600a2c3bc9e1516df533ca1bb1699b28304daafd3f8b3e12e7548d434f67b0",
    (True, "ap_statustext.csv"): "012967d1baa0cc129c49a96f8271144c2d0af3649affecd7cc5cf8fb6d17b370",
    (True, "camera.csv"): "127b049ea05724251833d70cc5c646a8059a0ecf11bdac9cb5c052473e47e4d0",
    (True, "commands.csv"): "c85312b82eb8786586a3f8f997838f7a380c4c16f1e1e15fec4db07ff01882d4",
    (True, "ekf.csv"): "21cc6511f38ec7489c9687633566bc11e9e725153f84a34554ff1bea93bb6c56",
    (True, "events.csv"): "fdd11ca5693cbd54b4ef0c54353e9fa85ed1f3405be5a9e6e9c414d3428ca2c4",
    (True, "flight.csv"): "e4732dc42772b1841835709b818e629f0ed514a0727a9bf2d5012d22f525222c",
    (True, "guidance.csv"): "6109ba7520f1d55fb21a04f40ce30905520ec9fdd2ecc029f89f441677f7abec",
    (True, "requests.csv"): "201a37250910276fc781ad91c52100a46ea2f134c3c9c1f354bfc6f3ba8f63f4",
    (True, "setpoints.csv"): "d057c3ee592549a915db82981122d3b2a5c6977364ee06261a71d4a1f8ba1694",
    (True, "truth.csv"): "edd640258e6ee562268da96c4326514fd131347a3bcb6a6d900adcdfdc5a56f3",
    (True, "uwb.csv"): "2aac0bed2c56f09b61d3d3eed8def802d1b7535c425668d04b6788034d317d60",
}


# The flight's last bits depend on the CPU: numpy's bundled OpenBLAS picks its kernels per CPU
# (measured on one AMD EPYC: its own kernel and Haswell's give one set of CSVs, SkylakeX's another,
# Nehalem's a third) and numpy and OpenCV dispatch SIMD code per CPU too. The digests are therefore
# taken in a child process with every such choice pinned to what any x86-64 CPU since 2008 runs:
# a recorded flight replays bit for bit on one machine and library build, not across CPUs.
PINNED_CPU_ENV = {
    "OPENBLAS_CORETYPE": "Nehalem",
    "OPENBLAS_NUM_THREADS": "1",
    "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR",
    "OPENCV_CPU_DISABLE": "AVX512_SKX,AVX2,FP16,AVX,SSE4_2,SSE4_1,POPCNT,SSSE3",
}

_CHILD = """
import hashlib, json, sys
from pathlib import Path
from companion.config import load_config, shipped_params_path
from companion_sitl.demo import run_demo
run, fusion = Path(sys.argv[1]), sys.argv[2] == "1"
over = {"sim": {"seed": 3, "gps_bias_m": [1.0, -0.5, 0.0], "pad_offset_m": [0.3, -0.2]}}
r = run_demo(load_config(shipped_params_path("sitl_short.toml"), overrides=over), fusion=fusion, run_dir=run)
assert r.delivered and r.returned, r.failure
print(json.dumps({f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in sorted(run.glob("*.csv"))}))
"""


@pytest.mark.slow
@pytest.mark.skipif(platform.machine() != "x86_64", reason="the digests are of x86-64 arithmetic (PINNED_CPU_ENV)")
@pytest.mark.parametrize("fusion", [False, True], ids=["gps-only", "fused"])
def test_run_folder_csvs_are_byte_identical_to_the_row_by_row_writer(tmp_path, fusion):
    env = {**os.environ, **PINNED_CPU_ENV}
    cmd = [sys.executable, "-c", _CHILD, str(tmp_path / "run"), "1" if fusion else "0"]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = {(fusion, name): digest for name, digest in json.loads(proc.stdout.strip().splitlines()[-1]).items()}
    want = {k: v for k, v in DIGESTS.items() if k[0] == fusion}
    assert got == want


def test_batched_log_writes_what_csv_writer_writes_row_by_row(tmp_path):
    """Floats (Python and numpy), ints, strings needing quotes, empty strings and NaN: the same
    bytes as ``csv.writer.writerow`` per row, across several flush periods and the close."""
    rng = np.random.default_rng(11)
    cols = ("time_s", "x_m", "n", "label", "y_m")
    rows = []
    for i in range(3000):
        x = float(rng.normal(0.0, 10.0 ** rng.integers(-12, 12)))
        rows.append(
            (
                i * 0.005,
                x if i % 3 else np.float64(x),
                int(rng.integers(-5, 10**9)),
                ["", "a,b", 'q"t', "ok"][i % 4],
                float("nan") if i % 17 == 0 else -0.0,
            )
        )
    ref = io.StringIO(newline="")
    w = csv.writer(ref)
    w.writerow(cols)
    for row in rows:
        w.writerow(row)
    with CsvLog(tmp_path / "a.csv", cols, max_queue=10**6, flush_period_s=0.01) as lg:
        for i, row in enumerate(rows):
            lg.write(row)
            if i % 700 == 0:
                lg._drain()  # as the writer thread would, mid-stream
    assert (tmp_path / "a.csv").read_bytes() == ref.getvalue().encode("utf-8")
    assert lg.written == len(rows) and lg.dropped == 0
