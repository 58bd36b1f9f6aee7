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
    (False, "ap_attitude.csv"): "cb00b1ab6ca5ed15afe87106aef90e9842a29d2f406e92b0a6657d7a6489f6ab",
    (False, "ap_global.csv"): "c46acfeb4c3c8b391fa6e5d644dfc29f01fa0015cfd087d0861be62f218bd3ec",
    (False, "ap_gps.csv"): "b6681cb88a54d336b50760b3d4e0ad65f8df9a11e8a35ae4d8547417eb9c5fb8",
    (False, "ap_home.csv"): "62df5f8352032c9a800775597db009f813dd5483367943a9a395230c3e84957c",
    (False, "ap_imu.csv"): "3fae326e37415b9442315d86798600b6d64530894ec97631bb5714a40312efcd",
    (False, "ap_position.csv"): "754a2ffbfb180cb75d1d135a052f96b035ebcac81e296324801547085046117f",
    (False, "ap_status.csv"): "e79bd5c1edaa056b145d2a3d5d2a45688ac0fce395bc9e1e1a2db210dab7032f",
    (False, "ap_statustext.csv"): "d9e68eae3982ef6b574534d2a336111bdcf0fac54d18c134bafd88ed6c295fcc",
    (False, "camera.csv"): "9a9d9425fde96b314d000395aa96c61b9ceb5f28e74d091fb58baef261322151",
    (False, "commands.csv"): "c85312b82eb8786586a3f8f997838f7a380c4c16f1e1e15fec4db07ff01882d4",
    (False, "ekf.csv"): "3c0ef73fbb26fa9ca884d887b9f91714a1668341ca51d0e90a57f1ee75b6b642",
    (False, "events.csv"): "01c606eef52fcb134468d250f8dd6e0c993eab02164becbbb8c520d128692f0f",
    (False, "flight.csv"): "32b17ffb837ba5517aeea71cd5e79162c0b5fd00e3a8fb20922fe13aac720cf8",
    (False, "guidance.csv"): "0dc5899b5c8ccfcf584c430665c2ba1d2904c879da3a0c7b115ce56e6ca748f5",
    (False, "requests.csv"): "849906730457e4713ff98ae1369c4a10ee9e5ffd0eb4f94b57c60f3ee056b58f",
    (False, "setpoints.csv"): "2b2f0ef8cee98e2fbb133c3c47ab6f91853a7a62bb99470e6b09af018974e4c9",
    (False, "truth.csv"): "5697e8a51179702790f179b974a14d22c0c7eefbd5c5a6cc40c0cf1dcebfbc29",
    (False, "uwb.csv"): "62b0204d2e49c8897570c237edf5dd971352b68222ae184b1c3284ba00637532",
    # fusion=True
    (True, "ap_attitude.csv"): "43ad12d0267427773174fe2b0a395bd6f0e6ae74123b1492a28f0cf7036c7d38",
    (True, "ap_global.csv"): "97409bd911ad1a6be12b5aad861b27d2e80d47547dd6a087e2e2abf6fbac3915",
    (True, "ap_gps.csv"): "71756f19b5e125fc98910bde9db113c96ede9004f0a54a3b2d212b787d8b02f7",
    (True, "ap_home.csv"): "12adee376aa2e394650b7b8606f39e4759349d11b65863c1df438c1f0b8fd14a",
    (True, "ap_imu.csv"): "754b2bc8c13ec78be7f46178f235398c3a4df040adbf7faf507de8de86af8d9c",
    (True, "ap_position.csv"): "7fac9e81b651860b16f3354381dda1ec4763afe29e7f996a78ea820f5ffec8f7",
    (True, "ap_status.csv"): "d4beb727739bc2f26f36b9fa50b7c5e2d4fc0e6c3832dc2c36f54aaad01ffd74",
    (True, "ap_statustext.csv"): "a3b7195f3ec142c5c60ff8d054570b613995f09d255b4e1e5b0da942a80dd5f2",
    (True, "camera.csv"): "f6760fde6f560207ff6545143cd1abc2b1209fd314faafe7cb9642f2c37e20d0",
    (True, "commands.csv"): "c85312b82eb8786586a3f8f997838f7a380c4c16f1e1e15fec4db07ff01882d4",
    (True, "ekf.csv"): "9445591f94094d6e7ee11cf9da2486998feba0ea2939219d3c459d946c54b0c1",
    (True, "events.csv"): "43bee5c7655283835cd0b5025fe68eca3b2c452ff5c001b867c380ae3bbd62af",
    (True, "flight.csv"): "03e3c1412ec6f11acf7a30425ab7cef72d9a34e42c7eb401febcb61f0c85e4a6",
    (True, "guidance.csv"): "7bc1e93d7b415a147474cbdb73fd9b4b4c0ce20506bf7dbfe9395eef41c83b4f",
    (True, "requests.csv"): "8e8cee9dd6acab982c3bec206615c995c0c1f0fc6b0fd45efd5de773df9baa19",
    (True, "setpoints.csv"): "9be0d5bd91dc5300d148d2ae84143b97f059c22cd9034c58bace552f1ab93254",
    (True, "truth.csv"): "0fbb5c7d1a10b9bf94323343c3b51f3b8545b57ae66ea09addc2256f944b9a9f",
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
