"""``companion report RUN``: PNG figures of a run folder, like the delivery and Dart papers' figures.

=========================  ===================================================================
``path.png``               planned vs flown path (delivery Fig. 8); simulator truth when the
                           folder has it (``companion demo``), else the estimate
``lyapunov.png``           the vector field's V over time (delivery Fig. 9)
``landing_3d.png``         position during the landing from each source -- autopilot GPS,
                           camera (pad observation turned into a vehicle position), UWB -- and
                           the fused EKF estimate, in the mission frame F_I (delivery Fig. 10)
``landing_axes.png``       the same per axis over time (delivery Fig. 11)
``gps_bias.png``           the EKF's GPS-bias state with its 2-sigma band (delivery Fig. 12)
=========================  ===================================================================

The campaign figures (landing scatter, Dart estimator comparison) are drawn beside the campaigns
(``companion_lab.campaign_output``); ``companion report`` hands them in as :class:`ExtraFigure`.

A figure whose inputs are missing is skipped and the reason reported; a malformed input file is
an error naming the file, line and column (:class:`~companion.flightlog.reader.LogFormatError`).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from companion.flightlog.mcap_encoding import MCAP_FILE
from companion.flightlog.reader import LogFormatError, Table, open_table, read_meta
from companion.flightlog.streams import META_FILE, STREAM_FILES, transform_from_json

log = logging.getLogger(__name__)

DPI = 110
COLOURS = {"gps": "tab:blue", "camera": "tab:orange", "uwb": "tab:green", "ekf": "tab:red", "truth": "k"}


@dataclass
class FigureResult:
    name: str
    title: str
    path: Path | None = None
    skipped: str = ""


class FigureSkipped(Exception):
    """A figure's inputs are missing (reported, not fatal)."""


@dataclass(frozen=True)
class ExtraFigure:
    """A figure :func:`make_report` draws beside the run's own, handed in by the caller (the
    campaign figures live with the campaigns): ``draw(run_dir, out_dir)`` returns the PNG written
    or raises :class:`FigureSkipped`."""

    name: str
    title: str
    draw: Callable[[Path, Path], Path]


def _table(run: Path, name: str, required: tuple[str, ...] = ()) -> Table:
    p = run / name
    if not p.exists() and not (run / MCAP_FILE).exists():
        raise FigureSkipped(f"{name} not found")
    try:
        return open_table(run, name, required or STREAM_FILES.get(name, ("time_s",)))
    except LogFormatError as err:
        if p.exists():
            raise
        raise FigureSkipped(f"{name} not found ({err})") from None


def _frame(meta: dict[str, Any]) -> Any:
    from companion.geometry.mission_frame import MissionFrame

    m = meta.get("mission")
    if not isinstance(m, dict):
        raise FigureSkipped(f"{META_FILE} has no mission frame (the mission never planned a path)")
    try:
        return MissionFrame(np.array(m["pad_ned_m"], dtype=float), float(m["heading_rad"]))
    except (KeyError, TypeError, ValueError) as err:
        raise LogFormatError(f"{META_FILE}: key 'mission': {type(err).__name__}: {err}") from None


def _to_mission(frame: Any, ned: np.ndarray) -> np.ndarray:
    """(n, 3) NED points -> (n, 3) points in F_I."""
    if ned.size == 0:
        return ned.reshape(0, 3)
    return (ned - frame.pad_ned) @ frame.R_ned_mission


# ---------------------------------------------------------------------------------------------
# sources


@dataclass
class _Sources:
    t_gps: np.ndarray
    gps: np.ndarray  # F_I
    t_cam: np.ndarray
    cam: np.ndarray
    cam_ambiguous: int
    t_uwb: np.ndarray
    uwb: np.ndarray
    t_ekf: np.ndarray
    ekf: np.ndarray
    window: tuple[float, float]
    pad_touchdown_s: float | None


def _sources(run: Path, meta: dict[str, Any]) -> _Sources:
    frame = _frame(meta)
    fusion = meta.get("fusion")
    if not isinstance(fusion, dict):
        why = "GPS-only flight" if not meta.get("landing") else "the landing fusion never started"
        raise FigureSkipped(f"no fused estimate in this run ({why})")
    try:
        T_world_pad = transform_from_json(fusion["T_world_pad"])
        T_body_camera = transform_from_json(fusion["T_body_camera"])
        T_pad_anchors = transform_from_json(fusion["T_pad_anchors"])
    except (KeyError, TypeError, ValueError) as err:
        raise LogFormatError(f"{run / META_FILE}: key 'fusion': {type(err).__name__}: {err}") from None
    ekf = _table(run, "ekf.csv")
    if len(ekf) == 0:
        raise FigureSkipped("ekf.csv has no rows (the filter was never initialised)")
    t_ekf = ekf.floats("time_s")
    p_ekf = np.column_stack([ekf.floats(c) for c in ("north_m", "east_m", "down_m")])

    pos = _table(run, "ap_position.csv")
    t_gps = pos.floats("time_s")
    p_gps = np.column_stack([pos.floats(c) for c in ("north_m", "east_m", "down_m")]).reshape(-1, 3)

    cam = _table(run, "camera.csv")
    t_cam = cam.floats("time_s")
    amb = cam.floats("ambiguous") > 0.5 if len(cam) else np.zeros(0, dtype=bool)
    if len(cam):
        R = np.column_stack([cam.floats(f"r{i}{j}") for i in range(3) for j in range(3)]).reshape(-1, 3, 3)
        tc = np.column_stack([cam.floats(c) for c in ("t_x_m", "t_y_m", "t_z_m")])
        # body origin in the camera frame, then in the pad frame (T_pad_camera = T_camera_pad^-1), then world
        t_cb = -T_body_camera.R.T @ T_body_camera.t
        p_pad = np.einsum("nji,nj->ni", R, t_cb[None, :] - tc)
        p_cam = p_pad @ T_world_pad.R.T + T_world_pad.t
    else:
        p_cam = np.zeros((0, 3))
    uwb = _table(run, "uwb.csv")
    t_uwb = uwb.floats("time_s")
    if len(uwb):
        T_world_anchors = T_world_pad @ T_pad_anchors
        p_uwb = T_world_anchors.apply(np.column_stack([uwb.floats(c) for c in ("x_m", "y_m", "z_m")]))
    else:
        p_uwb = np.zeros((0, 3))

    touchdown = None
    if (run / "events.csv").exists() or (run / MCAP_FILE).exists():
        ev = open_table(run, "events.csv", ("time_s", "kind", "detail"))
        for k in range(len(ev)):
            if ev.text(k, "kind") == "touchdown" and ev.text(k, "detail") == "pad":
                touchdown = float(ev.value(k, "time_s"))
                break
    local = np.concatenate([t_cam[~amb], t_uwb]) if len(cam) or len(uwb) else np.zeros(0)
    if local.size:
        t0 = float(local.min()) - 3.0
        t1 = touchdown + 2.0 if touchdown is not None else float(local.max()) + 3.0
    else:
        t0, t1 = float(t_ekf[0]), float(t_ekf[-1])
    t0 = max(t0, float(t_ekf[0]))
    return _Sources(
        t_gps,
        _to_mission(frame, p_gps),
        t_cam[~amb],
        _to_mission(frame, p_cam[~amb]),
        int(amb.sum()),
        t_uwb,
        _to_mission(frame, p_uwb),
        t_ekf,
        _to_mission(frame, p_ekf),
        (t0, t1),
        touchdown,
    )


def _in(t: np.ndarray, w: tuple[float, float]) -> np.ndarray:
    return (t >= w[0]) & (t <= w[1])


# ---------------------------------------------------------------------------------------------
# figures


def _fig_landing_3d(s: _Sources, out: Path) -> Path:
    """The final approach (EKF within 4 m of the pad horizontally), x and y to the same scale."""
    near = np.hypot(s.ekf[:, 0], s.ekf[:, 1]) <= 4.0
    t_start = float(s.t_ekf[np.argmax(near)]) if near.any() else s.window[0]
    w = (max(s.window[0], t_start), s.window[1])
    fig = plt.figure(figsize=(8, 7.5))
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    g, c, u, e = _in(s.t_gps, w), _in(s.t_cam, w), _in(s.t_uwb, w), _in(s.t_ekf, w)
    ax.plot(*s.gps[g].T, "-", color=COLOURS["gps"], lw=1.2, label="autopilot (GPS)")
    if c.any():
        ax.scatter(*s.cam[c].T, s=6, color=COLOURS["camera"], alpha=0.6, label="camera (ArUco pad)")
    if u.any():
        ax.scatter(*s.uwb[u].T, s=6, color=COLOURS["uwb"], alpha=0.6, label="UWB")
    ax.plot(*s.ekf[e].T, "-", color=COLOURS["ekf"], lw=1.8, label="EKF fusion")
    sq = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0], [-0.5, -0.5, 0]])
    ax.plot(*sq.T, "k-", lw=1.5, label="1 x 1 m pad")
    pts = np.vstack([s.gps[g], s.ekf[e], sq])
    half = max(1.0, float(np.max(np.abs(pts[:, :2])))) * 1.05
    ax.set_xlim(-half, half)
    ax.set_ylim(-half, half)
    ax.set_zlim(0.0, max(1.0, float(np.max(pts[:, 2]))) * 1.05)
    ax.set_xlabel("x [m] (towards the pad)")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m] (up)")
    ax.set_title(
        f"Final approach and landing, each source vs the fusion, in F_I (cf. delivery Fig. 10)\n"
        f"t = {w[0]:.1f} .. {w[1]:.1f} s",
        fontsize=10,
    )
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    f = out / "landing_3d.png"
    fig.savefig(f, dpi=DPI)
    plt.close(fig)
    return f


def _fig_landing_axes(s: _Sources, out: Path) -> Path:
    fig, axes = plt.subplots(3, 1, figsize=(10, 8.5), sharex=True)
    w = s.window
    g, c, u, e = _in(s.t_gps, w), _in(s.t_cam, w), _in(s.t_uwb, w), _in(s.t_ekf, w)
    for i, (ax, name) in enumerate(zip(axes, ("x [m]", "y [m]", "z [m] (up)"), strict=True)):
        ax.plot(s.t_gps[g], s.gps[g, i], "-", color=COLOURS["gps"], lw=1.0, label="autopilot (GPS)")
        if c.any():
            ax.plot(s.t_cam[c], s.cam[c, i], ".", ms=3, color=COLOURS["camera"], label="camera (ArUco pad)")
        if u.any():
            ax.plot(s.t_uwb[u], s.uwb[u, i], ".", ms=3, color=COLOURS["uwb"], label="UWB")
        ax.plot(s.t_ekf[e], s.ekf[e, i], "-", color=COLOURS["ekf"], lw=1.6, label="EKF fusion")
        if s.pad_touchdown_s is not None:
            ax.axvline(s.pad_touchdown_s, color="0.4", ls=":", lw=1)
        ax.set_ylabel(name)
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize=8, ncol=2)
    notes = ["dotted: touchdown on the pad"] if s.pad_touchdown_s is not None else []
    if s.cam_ambiguous:
        notes.append(f"{s.cam_ambiguous} ambiguous camera observation(s) not shown (never fused)")
    axes[-1].set_xlabel("time [s]" + (f"   ({'; '.join(notes)})" if notes else ""))
    axes[0].set_title("Landing: position per axis in F_I, each source vs the fusion (cf. delivery Fig. 11)")
    fig.tight_layout()
    f = out / "landing_axes.png"
    fig.savefig(f, dpi=DPI)
    plt.close(fig)
    return f


def _fig_gps_bias(run: Path, out: Path) -> Path:
    ekf = _table(run, "ekf.csv")
    if len(ekf) == 0:
        raise FigureSkipped("ekf.csv has no rows (GPS-only flight, or the filter was never initialised)")
    t = ekf.floats("time_s")
    xi = ekf.floats("xi") > 0.5
    fig, ax = plt.subplots(figsize=(10, 4.5))
    lo, hi = [], []
    for axis, col in (("north", "tab:blue"), ("east", "tab:orange"), ("down", "tab:green")):
        b = ekf.floats(f"bias_{axis}_m")
        sd = np.sqrt(np.maximum(ekf.floats(f"var_bias_{axis}_m2"), 0.0))
        ax.plot(t, b, "-", color=col, lw=1.4, label=f"b_{axis} [m]")
        ax.fill_between(t[xi], (b - 2 * sd)[xi], (b + 2 * sd)[xi], color=col, alpha=0.15, lw=0)
        if xi.any():
            lo.append(float(np.min(b[xi] - 2 * sd[xi])))
            hi.append(float(np.max(b[xi] + 2 * sd[xi])))
    if xi.any():
        t_xi = float(t[np.argmax(xi)])
        ax.axvline(t_xi, color="0.3", ls="--", lw=1)
        ax.text(t_xi, 0.02, " first pad-local fix (xi = 1)", transform=ax.get_xaxis_transform(), fontsize=8)
        span = max(hi) - min(lo)
        ax.set_ylim(min(lo) - 0.1 * span - 0.05, max(hi) + 0.1 * span + 0.05)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("estimated GPS bias [m]")
    ax.set_title(
        "EKF GPS-bias state with its 2-sigma band after the first pad-local fix (cf. delivery Fig. 12)", fontsize=10
    )
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left")
    fig.tight_layout()
    f = out / "gps_bias.png"
    fig.savefig(f, dpi=DPI)
    plt.close(fig)
    return f


def _fig_path_from_logs(run: Path, meta: dict[str, Any], out: Path) -> list[Path]:
    """Figs. 8-9 without simulator truth: the estimate the guidance flew on."""
    from companion.guidance.path import DeliveryPath

    frame = _frame(meta)
    m = meta["mission"]
    path = DeliveryPath(float(m["h_m"]), float(m["r_m"]), float(m["d_m"]))
    planned = path.sample(0.25, z_start=float(m["z_start_m"]))
    g = _table(run, "guidance.csv")
    t = g.floats("time_s")
    p = _to_mission(frame, np.column_stack([g.floats(c) for c in ("est_north_m", "est_east_m", "est_down_m")]))
    fig, ax = plt.subplots(figsize=(10, 4.5))
    ax.plot(planned[:, 0], planned[:, 2], "k--", lw=1, label="planned")
    ax.plot(p[:, 0], p[:, 2], "g-", lw=1.2, label="flown (estimate)")
    ax.set_xlabel("x [m] (towards the pad)")
    ax.set_ylabel("z [m] (up)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title("Delivery path in F_I, side view (cf. delivery Fig. 8)")
    fig.tight_layout()
    f1 = out / "path.png"
    fig.savefig(f1, dpi=DPI)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(9, 4))
    ax.plot(t, g.floats("lyapunov_m2"), "b-", lw=1, label="V (estimate) [m^2]")
    ax.set_yscale("symlog", linthresh=0.01)
    ax.set_xlabel("time [s]")
    ax.set_title("Vector field Lyapunov function (cf. delivery Fig. 9)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    f2 = out / "lyapunov.png"
    fig.savefig(f2, dpi=DPI)
    plt.close(fig)
    return [f1, f2]


def summary_missing(run: Path) -> str:
    """Why a run folder has no ``summary.json`` to read ("" when it has one): missing, or empty
    (written by a version that did not write it whole, on a disk that filled)."""
    f = run / "summary.json"
    try:
        if not f.read_text(encoding="utf-8").strip():
            return "empty (the flight's end could not write it)"
    except FileNotFoundError:
        return "missing"
    except OSError as err:
        return f"unreadable: {err.strerror}"
    return ""


def _check_plot_run_inputs(run: Path) -> None:
    """plot_run's inputs, read with errors that name the file and column."""
    try:
        summary = json.loads((run / "summary.json").read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise LogFormatError(f"{run / 'summary.json'}: not valid JSON: {err}") from None
    if not isinstance(summary, dict) or not summary.get("path"):
        raise FigureSkipped("summary.json has no planned path (the mission never planned one)")
    truth = Table(
        run / "truth.csv",
        ("time_s", "true_mission_x_m", "true_mission_y_m", "true_mission_z_m", "true_path_distance_m"),
    )
    for c in truth.header[2:]:
        if c != "phase":
            truth.floats(c)
    flight = Table(run / "flight.csv", ("time_s", "lyapunov_m2", "mission_x_m", "mission_z_m"))
    for c in ("time_s", "lyapunov_m2", "mission_x_m", "mission_z_m"):
        flight.floats(c)


# ---------------------------------------------------------------------------------------------


def make_report(
    run_dir: str | Path, out_dir: str | Path | None = None, extra: Sequence[ExtraFigure] = ()
) -> list[FigureResult]:
    """Every figure the run folder has inputs for, into ``out_dir`` (default ``run_dir``), then
    each of ``extra`` (the CLI hands in the campaign figures)."""
    from companion.flightlog.plots import plot_run

    run = Path(run_dir)
    if not run.is_dir():
        raise LogFormatError(f"{run}: not a folder")
    out = Path(out_dir) if out_dir is not None else run
    out.mkdir(parents=True, exist_ok=True)
    results: list[FigureResult] = []
    meta: dict[str, Any] | None = None
    meta_skip = ""
    if (run / META_FILE).exists() or (run / MCAP_FILE).exists():
        meta = read_meta(run)
    else:
        meta_skip = f"no {META_FILE} nor {MCAP_FILE} (not written by the flight recorder)"

    def attempt(names: list[str], titles: list[str], fn: Any) -> None:
        try:
            files = fn()
            files = files if isinstance(files, list) else [files]
            results.extend(FigureResult(n, t, f) for n, t, f in zip(names, titles, files, strict=True))
        except FigureSkipped as why:
            results.extend(FigureResult(n, t, None, str(why)) for n, t in zip(names, titles, strict=True))

    def fig8_9() -> list[Path]:
        no_summary = summary_missing(run)
        if not no_summary and (run / "truth.csv").exists() and (run / "flight.csv").exists():
            _check_plot_run_inputs(run)
            return plot_run(run, out)
        if meta is None:
            raise FigureSkipped(f"neither summary.json + truth.csv + flight.csv (simulator) nor {META_FILE}")
        if no_summary and (run / "truth.csv").exists():  # a demo's folder whose summary was not written
            log.warning("%s: %s; the path figures are drawn from the logs instead", run / "summary.json", no_summary)
        return _fig_path_from_logs(run, meta, out)

    def need_meta() -> dict[str, Any]:
        if meta is None:
            raise FigureSkipped(meta_skip)
        return meta

    attempt(["path.png", "lyapunov.png"], ["planned vs flown path (Fig. 8)", "Lyapunov function V (Fig. 9)"], fig8_9)

    def landing() -> list[Path]:
        s = _sources(run, need_meta())
        return [_fig_landing_3d(s, out), _fig_landing_axes(s, out)]

    attempt(
        ["landing_3d.png", "landing_axes.png"],
        ["landing position per source vs fusion, 3D (Fig. 10)", "landing position per axis (Fig. 11)"],
        landing,
    )
    attempt(["gps_bias.png"], ["estimated GPS bias (Fig. 12)"], lambda: (need_meta(), _fig_gps_bias(run, out))[1])
    for x in extra:
        attempt([x.name], [x.title], lambda x=x: x.draw(run, out))
    return results
