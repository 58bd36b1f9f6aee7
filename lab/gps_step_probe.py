"""What ArduCopter does with a GPS error that appears in flight (docs/weather.md): hover in GUIDED
on a zero velocity, step the SITL's GPS glitch (SIM_GPS1_GLTCH_X) by ``step_m`` north, hold, take
it away, hold; truth and the autopilot's LOCAL_POSITION_NED every 50 ms.

``python -m companion_lab.gps_step_probe OUT [--step-m 1]`` writes OUT/gps_step.csv and prints
the figures: how far the vehicle moved on truth and the estimate, and the time to 63 % of the
truth's move.

``--hover-noise-s 60`` hovers that long with the campaign's sensor noise on the SITL (the
[sim] gyro, accelerometer and barometer noise as ``--weather`` sets it), then as long without,
and prints how much the vehicle moved on truth and how far its estimate was from the truth in
each (OUT/hover_noise.csv; :func:`hover_figures`).

``--sine-hz 0.1,0.3,...`` drives the glitch as a sine of ``--amplitude-m`` at each frequency in
turn instead (OUT/gps_sine.csv) and prints the frequency response: the truth's move against the
GPS error's opposite, gain and phase lag per frequency (:func:`sine_response`). With
``--wind-mean-m-s M`` it drives the wind from the north instead, M plus a sine of
``--amplitude-m`` in m/s (SIM_WIND_SPD; OUT/wind_sine.csv), and the gain is the truth's move north
in m per m/s of wind blowing north (the SITL's wind at 60 m: it fades towards the ground).
With ``--velocity`` it drives the velocity setpoint north instead, a sine of ``--amplitude-m`` in
m/s (OUT/velocity_sine.csv), and the gain is the truth's velocity against the setpoint.
``--alt-m`` sets the hover height (6 m).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import numpy as np

from companion.autopilot.interface import Autopilot
from companion.config import CompanionConfig
from companion.guidance.setpoint import VelocitySetpoint
from companion_firmware.real_vehicle import real_vehicle
from companion_firmware.truth_feed import MavlinkTruth
from companion_lab.firmware_probe import hover_in_offboard, write_csv
from companion_lab.real_weather import WIND_TC_S, FirmwareWeather, glitch_deg, static_params
from companion_sitl.params import SimConfig
from companion_sitl.vehicle import GaussMarkov, SimVehicle

COLUMNS = ("t_s", "phase", "truth_n_m", "est_n_m")
SINE_COLUMNS = ("t_s", "freq_hz", "gps_error_n_m", "truth_n_m", "est_n_m")
WIND_SINE_COLUMNS = ("t_s", "freq_hz", "wind_n_m_s", "truth_n_m", "est_n_m")
VELOCITY_SINE_COLUMNS = ("t_s", "freq_hz", "sp_n_m_s", "truth_vn_m_s", "est_vn_m_s")
SINE_SETTLE_CYCLES = 1.5  # the transient left out of each frequency's fit


@asynccontextmanager
async def _hovering(out_dir: Path, alt_m: float) -> AsyncIterator[tuple[Autopilot, MavlinkTruth]]:
    """ArduCopter SITL started in ``out_dir``, healthy (within 120 s) and hovering at ``alt_m``
    in GUIDED on a zero velocity: the backend and the truth link; the backend closed after."""
    async with real_vehicle("ardupilot", out_dir) as rv:
        ap = rv.backend(CompanionConfig(autopilot="ardupilot"))
        await ap.connect(timeout_s=20.0)
        try:
            t_end = time.monotonic() + 120.0
            while not ((st := ap.telemetry.status) is not None and st.healthy):
                if time.monotonic() > t_end:
                    raise TimeoutError("ArduCopter SITL not healthy within 120 s")
                await asyncio.sleep(0.2)
            await hover_in_offboard(ap, rv.truth, alt_m)
            yield ap, rv.truth
        finally:
            await ap.close()


def _sine_seconds(f: float) -> float:
    """How long a frequency is driven: SINE_SETTLE_CYCLES, then at least 6 cycles and 12 s (0: a
    5 s hover)."""
    return 5.0 if f == 0.0 else (SINE_SETTLE_CYCLES + max(6.0, 12.0 * f)) / f


async def probe(out_dir: Path, step_m: float = 1.0, alt_m: float = 6.0) -> dict[str, Any]:
    rows: list[tuple[float, str, float, float]] = []
    async with _hovering(out_dir, alt_m) as (ap, truth):
        t0 = time.monotonic()

        async def hold(seconds: float, phase: str) -> None:
            t_stop = time.monotonic() + seconds
            while time.monotonic() < t_stop:
                ap.set_velocity_ned(VelocitySetpoint(0.0, 0.0, 0.0, 0.0))
                p = ap.telemetry.position_ned
                if p is not None:
                    rows.append((time.monotonic() - t0, phase, truth.pn, p.north_m))
                await asyncio.sleep(0.05)

        origin = truth.origin
        assert origin is not None
        await hold(8.0, "hover")
        await asyncio.to_thread(truth.set_param, "SIM_GPS1_GLTCH_X", glitch_deg(step_m, 0.0, origin.lat_deg)[0])
        await hold(15.0, "glitch")
        await asyncio.to_thread(truth.set_param, "SIM_GPS1_GLTCH_X", 0.0)
        await hold(12.0, "cleared")
    write_csv(out_dir / "gps_step.csv", COLUMNS, rows)
    return figures(rows, step_m)


async def sine_probe(
    out_dir: Path,
    freqs_hz: list[float],
    amplitude_m: float = 0.1,
    alt_m: float = 6.0,
    wind_mean_m_s: float = 0.0,
    velocity: bool = False,
) -> list[dict[str, float]]:
    """Hover in GUIDED on a zero velocity and drive the GPS glitch north as a sine of
    ``amplitude_m`` at each frequency in turn (SINE_SETTLE_CYCLES, then at least 6 cycles and
    12 s), sent every 50 ms; returns :func:`sine_response`. ``wind_mean_m_s`` > 0: the wind from
    the north instead, that mean plus the sine (m/s); ``velocity``: the velocity setpoint north
    (m/s), the truth's and the estimate's velocity against it."""
    rows: list[tuple[float, float, float, float, float]] = []
    async with _hovering(out_dir, alt_m) as (ap, truth):
        origin = truth.origin
        assert origin is not None
        if wind_mean_m_s > 0.0:  # from the north, the SITL's low-pass short as the campaign sets it
            for name, value in (("SIM_WIND_DIR", 0.0), ("SIM_WIND_TURB", 0.0), ("SIM_WIND_TC", WIND_TC_S)):
                await asyncio.to_thread(truth.set_param, name, value)
            await asyncio.to_thread(truth.set_param, "SIM_WIND_SPD", wind_mean_m_s)
        t0 = time.monotonic()
        for f in [0.0, *freqs_hz]:  # 0: 5 s of hover first
            seconds = _sine_seconds(f)
            tf = time.monotonic()
            while (now := time.monotonic()) < tf + seconds:
                x = amplitude_m * math.sin(2.0 * math.pi * f * (now - tf))
                if not velocity and wind_mean_m_s > 0.0:
                    truth.send_param("SIM_WIND_SPD", wind_mean_m_s + x)
                    x = -(wind_mean_m_s + x)  # the air's velocity north
                elif not velocity:
                    truth.send_param("SIM_GPS1_GLTCH_X", glitch_deg(x, 0.0, origin.lat_deg)[0])
                ap.set_velocity_ned(VelocitySetpoint(x if velocity else 0.0, 0.0, 0.0, 0.0))
                p = ap.telemetry.position_ned
                if p is not None:  # positions, or velocities against a velocity setpoint
                    y = (truth.vn, p.north_m_s) if velocity else (truth.pn, p.north_m)
                    rows.append((now - t0, f, x, *y))
                await asyncio.sleep(0.05)
        if not velocity:
            await asyncio.to_thread(truth.set_param, "SIM_WIND_SPD" if wind_mean_m_s > 0.0 else "SIM_GPS1_GLTCH_X", 0.0)
    if velocity:
        write_csv(out_dir / "velocity_sine.csv", VELOCITY_SINE_COLUMNS, rows)
        return sine_response(rows, input_sign=1.0)
    if wind_mean_m_s > 0.0:
        write_csv(out_dir / "wind_sine.csv", WIND_SINE_COLUMNS, rows)
        return sine_response(rows, input_sign=1.0)
    write_csv(out_dir / "gps_sine.csv", SINE_COLUMNS, rows)
    return sine_response(rows)


HOVER_COLUMNS = ("t_s", "phase", "truth_n_m", "truth_e_m", "est_n_m", "est_e_m")


async def hover_noise_probe(out_dir: Path, seconds: float, alt_m: float = 6.0) -> dict[str, dict[str, float]]:
    """Hover in GUIDED on a zero velocity for ``seconds`` with the sensor noise of a default
    [sim] section set as the weather campaign sets it, then ``seconds`` without; returns
    :func:`hover_figures`."""
    rows: list[tuple[float, str, float, float, float, float]] = []
    w = FirmwareWeather.of(SimConfig())
    async with _hovering(out_dir, alt_m) as (ap, truth):
        hover = await asyncio.to_thread(truth.get_param, "MOT_THST_HOVER")
        noisy = static_params(w, hover)
        t0 = time.monotonic()
        for phase, params in (("noise", noisy), ("quiet", [(name, 0.0) for name, _ in noisy[:3]])):
            for name, value in params:
                await asyncio.to_thread(truth.set_param, name, value)
            t_stop = time.monotonic() + seconds
            while time.monotonic() < t_stop:
                ap.set_velocity_ned(VelocitySetpoint(0.0, 0.0, 0.0, 0.0))
                p = ap.telemetry.position_ned
                if p is not None:
                    rows.append((time.monotonic() - t0, phase, truth.pn, truth.pe, p.north_m, p.east_m))
                await asyncio.sleep(0.05)
    write_csv(out_dir / "hover_noise.csv", HOVER_COLUMNS, rows)
    return hover_figures(rows)


def _moved(t: np.ndarray, x: np.ndarray, dt_s: float) -> np.ndarray:
    """x(t + dt_s) - x(t) for each sample with one dt_s later (the first at or after it)."""
    k = np.searchsorted(t, t + dt_s)
    ok = k < len(t)
    return x[k[ok]] - x[ok]


def hover_figures(rows: list[tuple[float, str, float, float, float, float]]) -> dict[str, dict[str, float]]:
    """Per phase, after its first 5 s: the truth's horizontal spread about its mean (RMS, m), its
    speed (RMS over 0.5 s differences, m/s), and the estimate minus the truth less its mean (RMS,
    m) with how much that error changes in 1 s (RMS, m)."""
    out = {}
    for phase in dict.fromkeys(r[1] for r in rows):
        seg = [r for r in rows if r[1] == phase]
        seg = [r for r in seg if r[0] >= seg[0][0] + 5.0]
        if len(seg) < 60:
            raise ValueError(f"phase {phase!r}: {len(seg)} samples after its first 5 s, need 60")
        a = np.array([r[2:] for r in seg])
        t = np.array([r[0] for r in seg])
        tr, err = a[:, 0:2], a[:, 2:4] - a[:, 0:2]
        err -= err.mean(axis=0)

        out[phase] = {
            "truth_rms_m": float(np.sqrt(((tr - tr.mean(axis=0)) ** 2).sum(axis=1).mean())),
            "truth_speed_rms_m_s": float(np.sqrt((_moved(t, tr, 0.5) ** 2).sum(axis=1).mean()) / 0.5),
            "estimate_error_rms_m": float(np.sqrt((err**2).sum(axis=1).mean())),
            "estimate_error_1s_rms_m": float(np.sqrt((_moved(t, err, 1.0) ** 2).sum(axis=1).mean())),
        }
    return out


def _phasor(t: np.ndarray, f: float, y: np.ndarray) -> complex:
    """y ~ Re(p exp(i 2 pi f t)) + a + b t, least squares; returns p."""
    a = np.column_stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones_like(t), t - t.mean()])
    c = np.linalg.lstsq(a, y, rcond=None)[0]
    return complex(c[0], -c[1])


class _SineError(GaussMarkov):
    """A GPS error north that is a sine of the vehicle's time (the profile's side of the probe)."""

    def __init__(self, vehicle: SimVehicle) -> None:
        super().__init__(0.0, 1.0)
        self.vehicle = vehicle
        self.freq_hz = 0.0
        self.amplitude_m = 0.0
        self.t0_s = 0.0

    def step(self, dt: float, n: float) -> float:
        t = self.vehicle.time_s + dt - self.t0_s  # the value at the end of the step
        self.x = self.amplitude_m * math.sin(2.0 * math.pi * self.freq_hz * t) if self.freq_hz > 0.0 else 0.0
        return self.x


def profile_sine_response(
    profile: str,
    freqs_hz: list[float],
    amplitude_m: float = 0.1,
    alt_m: float = 6.0,
    wind_mean_m_s: float = 0.0,
    velocity: bool = False,
) -> list[dict[str, float]]:
    """The same probe flown by the embedded vehicle with a firmware profile (sitl/profiles.py),
    calm air and no GPS wander but the sine: what the profile says the firmware does."""
    cfg = SimConfig.model_validate({"profile": profile, "gps_walk_m": 0.0, "gps_noise_m": 0.0, "gust_std_m_s": 0.0})
    v = SimVehicle(cfg)
    sine = _SineError(v)
    v._walk[0] = sine
    zero = VelocitySetpoint(0.0, 0.0, 0.0, 0.0)
    while not v.healthy:
        v.step_to(v.time_s + 0.5)
    v.arm()
    v.takeoff(alt_m)
    while v.pd > -(alt_m - 0.05):
        v.step_to(v.time_s + 0.05)
    for _ in range(60):
        v.set_velocity(zero)
        v.step_to(v.time_s + 0.05)
    v.start_offboard()
    rows: list[tuple[float, float, float, float, float]] = []
    for f in [0.0, *freqs_hz]:
        seconds = _sine_seconds(f)
        t_stop = v.time_s + seconds
        if velocity:  # recorded as the real probe does: the state when the setpoint is sent
            t0 = v.time_s
            while v.time_s < t_stop:
                x = amplitude_m * math.sin(2.0 * math.pi * f * (v.time_s - t0))
                rows.append((v.time_s, f, x, v.vn, v.position_ned().north_m_s))
                v.set_velocity(VelocitySetpoint(x, 0.0, 0.0, 0.0))
                v.step_to(v.time_s + 0.05)
            continue
        if wind_mean_m_s > 0.0:
            t0 = v.time_s
            while v.time_s < t_stop:
                x = wind_mean_m_s + amplitude_m * math.sin(2.0 * math.pi * f * (v.time_s - t0))
                v.set_wind(x, 0.0)  # from the north, held for the next 50 ms as the SITL's is
                v.set_velocity(zero)
                v.step_to(v.time_s + 0.05)
                rows.append((v.time_s, f, -x, v.pn, v.position_ned().north_m))
            continue
        sine.freq_hz, sine.amplitude_m, sine.t0_s = f, amplitude_m, v.time_s
        while v.time_s < t_stop:
            v.set_velocity(zero)
            v.step_to(v.time_s + 0.05)
            rows.append((v.time_s, f, sine.x, v.pn, v.position_ned().north_m))
    return sine_response(rows, input_sign=1.0 if wind_mean_m_s > 0.0 or velocity else -1.0)


def sine_response(
    rows: list[tuple[float, float, float, float, float]], input_sign: float = -1.0
) -> list[dict[str, float]]:
    """Per frequency (rows: t, f, input, truth, estimate), the truth's move against
    ``input_sign`` x the input (-1 for a GPS error: a vehicle held on an estimate that takes the
    error moves by -error at DC): gain and phase lag (deg), each signal least-squares fitted with
    a sine, a cosine and a straight line over the samples after SINE_SETTLE_CYCLES; the
    estimate's move the same way."""
    out = []
    for f in sorted({r[1] for r in rows if r[1] > 0.0}):
        seg = [r for r in rows if r[1] == f]
        t_start = seg[0][0] + SINE_SETTLE_CYCLES / f
        seg = [r for r in seg if r[0] >= t_start]
        if len(seg) < 20:
            raise ValueError(f"{f} Hz: {len(seg)} samples after the transient, need 20")
        t = np.array([r[0] for r in seg])
        u = input_sign * _phasor(t, f, np.array([r[2] for r in seg]))
        y = _phasor(t, f, np.array([r[3] for r in seg]))
        e = _phasor(t, f, np.array([r[4] for r in seg]))
        out.append(
            {
                "freq_hz": f,
                "gain": abs(y) / abs(u),
                "phase_lag_deg": -math.degrees(np.angle(y / u)),
                "estimate_gain": abs(e) / abs(u),
            }
        )
    return out


def figures(rows: list[tuple[float, str, float, float]], step_m: float) -> dict[str, Any]:
    """The truth's and the estimate's move over the glitch (its last 2 s against the hover's
    last sample) and the time the truth took to 63 % of the step, the other way."""
    hover = [r for r in rows if r[1] == "hover"]
    glitch = [r for r in rows if r[1] == "glitch"]
    if not hover or not glitch:
        raise ValueError("no hover or glitch samples recorded")
    b = hover[-1]
    end = [r for r in glitch if r[0] >= glitch[-1][0] - 2.0]
    truth_move = sum(r[2] - b[2] for r in end) / len(end)
    est_move = sum(r[3] - b[3] for r in end) / len(end)
    t63 = next((r[0] - glitch[0][0] for r in glitch if -(r[2] - b[2]) * step_m >= 0.632 * step_m * step_m), None)
    return {"step_m": step_m, "truth_move_m": truth_move, "estimate_move_m": est_move, "truth_63pct_s": t63}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--step-m", type=float, default=1.0)
    ap.add_argument("--sine-hz", type=str, default="", help="comma-separated frequencies: the sine probe")
    ap.add_argument("--amplitude-m", type=float, default=0.1, help="the sine probe's GPS error amplitude")
    ap.add_argument("--profile", default="", help="fly the sine probe on this firmware profile instead")
    ap.add_argument("--wind-mean-m-s", type=float, default=0.0, help="the sine probe drives the wind, about this mean")
    ap.add_argument("--velocity", action="store_true", help="the sine probe drives the velocity setpoint (m/s)")
    ap.add_argument("--alt-m", type=float, default=6.0, help="the hover height")
    ap.add_argument("--hover-noise-s", type=float, default=0.0, help="the sensor-noise hover probe, seconds a phase")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    if a.hover_noise_s:
        for phase, figs in asyncio.run(hover_noise_probe(a.out, a.hover_noise_s, a.alt_m)).items():
            print(phase, "  ".join(f"{k} {v:.4f}" for k, v in figs.items()))
        return
    if a.sine_hz:
        freqs = [float(x) for x in a.sine_hz.split(",")]
        if a.profile:
            res = profile_sine_response(a.profile, freqs, a.amplitude_m, a.alt_m, a.wind_mean_m_s, a.velocity)
        else:
            res = asyncio.run(sine_probe(a.out, freqs, a.amplitude_m, a.alt_m, a.wind_mean_m_s, a.velocity))
        for r in res:
            print("  ".join(f"{k} {v:.3f}" for k, v in r.items()))
        return
    for k, v in asyncio.run(probe(a.out, a.step_m, a.alt_m)).items():
        print(f"{k:18s} {v}")


if __name__ == "__main__":
    main()
