"""The flight logs' bytes: the batched writer (one shared writer thread, ``writerows`` per
period) writes exactly the pinned files.

``DIGESTS`` are the SHA-256 of every CSV of the short seeded flight (GPS-only and fused), taken
with the CPU-dependent arithmetic pinned (``PINNED_CPU_ENV``, below), so they hold on any x86-64
machine. They pin the flight as well as the format: regenerate them when the flight itself is
meant to change."""

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
    (False, "ap_attitude.csv"): "dcbd443553043e19287318eff948b97f72c5263cf711b279b0aee5288c7f1d1d",
    (False, "ap_global.csv"): "a4995c095b2456a38ba4fe629ada484734bbdafd86b32f2bdb502b95305ec9c6",
    (False, "ap_gps.csv"): "3e8d383a19576cddfc073ead9e1bf8c641cca4e49581534914f7205273675a81",
    (False, "ap_home.csv"): "3540360a2c816caa0fc9ee9c5053581577114db50a49b41921a382c5cc70591a",
    (False, "ap_imu.csv"): "4929acff7480eb3f0946ac0c6b709012b1c3c53fe47bf31412355d65928dddbe",
    (False, "ap_position.csv"): "3439694ad0a564d99904aee9ac22c68ea44904f132d063f9e744db971550235a",
    (False, "ap_status.csv"): "6bd161c0bda20a733c4e7304b50227d6329c4c8b5f918bb10a66042f68be9709",
    (False, "ap_statustext.csv"): "41063fb65c0990db1bbd08b349f4fc22c5bf6de646636091e6d5efd96dc7da06",
    (False, "camera.csv"): "9a9d9425fde96b314d000395aa96c61b9ceb5f28e74d091fb58baef261322151",
    (False, "commands.csv"): "c85312b82eb8786586a3f8f997838f7a380c4c16f1e1e15fec4db07ff01882d4",
    (False, "ekf.csv"): "3c0ef73fbb26fa9ca884d887b9f91714a1668341ca51d0e90a57f1ee75b6b642",
    (False, "events.csv"): "a062baa0299e60e6a4ee5fb6436200cf17c896ff4521768b302dc82fc748fcda",
    (False, "flight.csv"): "c751580731eab4220fda8920b7bc74faab8ee8fa78ac21c07d7c30da572f6bc6",
    (False, "guidance.csv"): "5377e0e9789ac492824894c6fe3ea996e99ce0e83f73c7c3d3aae369aa1b8501",
    (False, "requests.csv"): "22eefe813465bef0ead8f7ddf5066d1bc27f88421d1fb2ee081e38d905921fdb",
    (False, "setpoints.csv"): "feffb8ee70affb0851964d5dc6acb33113861fedd77c5ee8acf7692283a995f4",
    (False, "truth.csv"): "b6273bbc5d83eb6ae0e90341e27bd19439d5e146db4fdb051a4d4faf53863b4c",
    (False, "uwb.csv"): "62b0204d2e49c8897570c237edf5dd971352b68222ae184b1c3284ba00637532",
    # fusion=True
    (True, "ap_attitude.csv"): "6bb7d059d218807488d82496699730477090998268ed6e57311c224f7491f632",
    (True, "ap_global.csv"): "e815f38d1d90db1ecf54f2abe1ee3d0ec002c5d110b22970baaa5b958075770c",
    (True, "ap_gps.csv"): "ece60b7e80ef01bab8271b292d31bf5405c503739dc3a462ffb1d0fd4e8e405b",
    (True, "ap_home.csv"): "12adee376aa2e394650b7b8606f39e4759349d11b65863c1df438c1f0b8fd14a",
    (True, "ap_imu.csv"): "f5c400c35b4a641a16aa2bea66e2e41c5c10a0589ba4d617c6682a74337941d4",
    (True, "ap_position.csv"): "fd85492218c4331bd9e203a44af67081cda93515ee2bb3988a51c0967bde08ed",
    (True, "ap_status.csv"): "a9ebd7da9038db9b0d7c7c00bdb4c2f2254b2737443b3ae37a237ad5a87c4299",
    (True, "ap_statustext.csv"): "43834e15e79c81842ff0acec2d61ff9c2609fdf38cd794ee54cc91d3646226b7",
    (True, "camera.csv"): "f6760fde6f560207ff6545143cd1abc2b1209fd314faafe7cb9642f2c37e20d0",
    (True, "commands.csv"): "c85312b82eb8786586a3f8f997838f7a380c4c16f1e1e15fec4db07ff01882d4",
    (True, "ekf.csv"): "56aff71f88d018d7e2cdbbb99a4b86a3f99ef24ab3b7160d5f48957ac00ae5b6",
    (True, "events.csv"): "43bee5c7655283835cd0b5025fe68eca3b2c452ff5c001b867c380ae3bbd62af",
    (True, "flight.csv"): "e5e4d8510660839decf06067f2731358f116538b5e0f09004cd5e7b3d475c37d",
    (True, "guidance.csv"): "4cbec2ca604262b693cae5e07147e325451de94a7e930dc97de1e23ef026aa7c",
    (True, "requests.csv"): "8e8cee9dd6acab982c3bec206615c995c0c1f0fc6b0fd45efd5de773df9baa19",
    (True, "setpoints.csv"): "aabe4187a417a021b3033d192e2b96ff84a037fd349162f794a3c610c7fb1b92",
    (True, "truth.csv"): "d53d2bca90052d67d95a0a95c6fa1160fe549b7a971b3469548b52f97fc72d74",
    (True, "uwb.csv"): "977867525d7300bf63b1e2cba157fec2e7fd468b0cf4e387983b414971e0af2c",
}


# The flight's last bits depend on the CPU: numpy's bundled OpenBLAS picks its kernels per CPU
# (on one machine Haswell's and SkylakeX's kernels give different CSVs) and numpy and OpenCV
# dispatch SIMD code per CPU too. The digests are therefore taken in a child process with every
# such choice pinned to what any x86-64 CPU since 2008 runs:
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
from companion_lab.demo import run_demo
run, fusion = Path(sys.argv[1]), sys.argv[2] == "1"
over = {"sim": {"seed": 3, "gps_bias_m": [1.0, -0.5, 0.0], "pad_offset_m": [0.3, -0.2]}}
r = run_demo(load_config(shipped_params_path("sitl_short.toml"), overrides=over), fusion=fusion, run_dir=run)
assert r.delivered and r.returned, r.failure
print(json.dumps({f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in sorted(run.glob("*.csv"))}))
"""


@pytest.mark.flight
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
