"""What ArduCopter does with a GPS error that appears in flight (docs/weather.md): hover in GUIDED
on a zero velocity, step the SITL's GPS glitch (SIM_GPS1_GLTCH_X) by ``step_m`` north, hold, take
it away, hold; truth and the autopilot's LOCAL_POSITION_NED every 50 ms.

``python -m companion_lab.gps_step_probe OUT [--step-m 1]`` writes OUT/gps_step.csv and prints
the figures: how far the vehicle moved on truth and the estimate, and the time to 63 % of the
truth's move.
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import time
from pathlib import Path
from typing import Any

from companion.config import CompanionConfig
from companion.guidance.setpoint import VelocitySetpoint
from companion_firmware.real_vehicle import real_vehicle
from companion_lab.firmware_probe import hover_in_offboard
from companion_lab.real_weather import glitch_deg

COLUMNS = ("t_s", "phase", "truth_n_m", "est_n_m")


async def probe(out_dir: Path, step_m: float = 1.0, alt_m: float = 6.0) -> dict[str, Any]:
    rows: list[tuple[float, str, float, float]] = []
    async with real_vehicle("ardupilot", out_dir) as rv:
        ap = rv.backend(CompanionConfig(autopilot="ardupilot"))
        await ap.connect(timeout_s=20.0)
        truth = rv.truth
        try:
            t_end = time.monotonic() + 120.0
            while not ((st := ap.telemetry.status) is not None and st.healthy):
                if time.monotonic() > t_end:
                    raise TimeoutError("ArduCopter SITL not healthy within 120 s")
                await asyncio.sleep(0.2)
            await hover_in_offboard(ap, truth, alt_m)
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
        finally:
            await ap.close()
    with open(out_dir / "gps_step.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        w.writerows(rows)
    return figures(rows, step_m)


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
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    for k, v in asyncio.run(probe(a.out, a.step_m)).items():
        print(f"{k:18s} {v}")


if __name__ == "__main__":
    main()
