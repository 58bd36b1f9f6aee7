"""PNG plots of a run, like the delivery paper's figures (matplotlib, headless Agg backend)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from companion.flightlog.csvlog import read_csv
from companion.guidance.path import DeliveryPath


def _floats(col: list[str]) -> np.ndarray:
    return np.array([float(v) if v not in ("", "nan") else math.nan for v in col])


def plot_run(run_dir: str | Path, out_dir: str | Path | None = None) -> list[Path]:
    """Write path.png (delivery Fig. 8) and lyapunov.png (Fig. 9) into ``out_dir`` (default ``run_dir``)."""
    run = Path(run_dir)
    dest = Path(out_dir) if out_dir is not None else run
    dest.mkdir(parents=True, exist_ok=True)
    summary = json.loads((run / "summary.json").read_text())
    if not summary.get("path"):
        raise ValueError(f"{run / 'summary.json'}: no planned path recorded (the mission never planned one)")
    p = summary["path"]
    path = DeliveryPath(p["h_m"], p["r_m"], p["d_m"])
    planned = path.sample(0.25, z_start=p["z_start_m"])
    truth = read_csv(run / "truth.csv")
    flight = read_csv(run / "flight.csv")
    out = []

    # Fig. 8: planned (dashed) vs flown path, in the mission frame F_I
    fig = plt.figure(figsize=(11, 5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    tx, ty, tz = (_floats(truth[k]) for k in ("true_mission_x_m", "true_mission_y_m", "true_mission_z_m"))
    ax.plot(planned[:, 0], planned[:, 1], planned[:, 2], "k--", lw=1, label="planned")
    ax.plot(tx, ty, tz, "g-", lw=1.2, label="flown (truth)")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    half = max(5.0, float(np.nanmax(np.abs(ty))) if ty.size else 5.0)
    ax.set_ylim(-half, half)
    ax.set_title("Delivery path in F_I (cf. delivery Fig. 8)")
    ax.legend(loc="upper left")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.plot(planned[:, 0], planned[:, 2], "k--", lw=1, label="planned")
    ax2.plot(tx, tz, "g-", lw=1.2, label="flown (truth)")
    ex, ez = _floats(flight["mission_x_m"]), _floats(flight["mission_z_m"])
    ax2.plot(ex, ez, "b:", lw=1, label="flown (estimate)")
    ax2.set_xlabel("x [m] (towards the pad)")
    ax2.set_ylabel("z [m] (up)")
    ax2.set_title("Side view")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.grid(True, alpha=0.3)
    ax2.legend()
    fig.tight_layout()
    f = dest / "path.png"
    fig.savefig(f, dpi=110)
    plt.close(fig)
    out.append(f)

    # Fig. 9: Lyapunov function V over time (estimate) and the true distance to the path
    fig, ax = plt.subplots(figsize=(9, 4))
    t = _floats(flight["time_s"])
    V = _floats(flight["lyapunov_m2"])
    ax.plot(t, V, "b-", lw=1, label="V (estimate) [m^2]")
    tt = _floats(truth["time_s"])
    ax.plot(tt, _floats(truth["true_path_distance_m"]), "g-", lw=0.8, alpha=0.7, label="distance to path (truth) [m]")
    ax.set_xlabel("time [s]")
    ax.set_title("Vector field Lyapunov function (cf. delivery Fig. 9)")
    ax.set_yscale("symlog", linthresh=0.01)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    f = dest / "lyapunov.png"
    fig.savefig(f, dpi=110)
    plt.close(fig)
    out.append(f)
    return out
