"""The moving pad on real firmware (docs/moving-pad.md): the sitl_short delivery onto a pad that
drives off during the approach, flown on ArduCopter SITL or PX4 SIH with the camera and UWB rendered
from the SITL's truth (firmware/truth_harness.py) and scored on truth at the touchdown.

The pad starts ``MOVING_PAD_START_S`` after the take-off (the arc before the descent on this path),
speeds up at 0.5 m/s^2 on a course drawn from the seed (the embedded campaign's draw,
``moving_pad_course_deg``) and stops dead at the vehicle's first ground contact (a SITL's ground
cannot carry the vehicle). One SITL per landing::

    python -m companion_lab.real_moving_pad --firmware ardupilot --seed 200100 --n 4
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import time
from pathlib import Path
from typing import Any

from companion.config import shipped_params_path
from companion_firmware.real_vehicle import REAL_AUTOPILOTS, real_vehicle
from companion_firmware.truth_harness import fly_on_truth, true_pad_ne
from companion_lab.campaign_landing import moving_pad_course_deg
from companion_lab.real_campaign import _write_trace, firmware_tuning
from companion_sitl.params import SimulatedConfig, load_simulated_config

log = logging.getLogger(__name__)

#: seconds from the take-off to the pad driving off: the arc before the descent on sitl_short's
#: path, so the pad is seen standing first and drives through the whole descent (docs/moving-pad.md)
MOVING_PAD_START_S = 17.0

#: boot parameters of a moving-pad flight. ArduCopter: GUID_OPTIONS bit 4 (DoNotStabilizePositionXY):
#: its GUIDED velocity control also holds a position target integrated from the setpoints, which
#: runs on when the SITL's ground stops the vehicle at the pad's speed, winds the position
#: controller up to the lean limit and keeps the land detector from firing (docs/moving-pad.md).
#: The companion closes the position loop itself, on the pad-relative EKF.
MOVING_PAD_BOOT_PARAMS: dict[str, dict[str, float]] = {"ardupilot": {"GUID_OPTIONS": 16.0}, "px4": {}}

LANDING_TIMEOUT_S = {"px4": 150.0, "ardupilot": 120.0}


def moving_pad_config(
    autopilot: str, connection: str, seed: int, speed_m_s: float = 2.0, start_s: float = MOVING_PAD_START_S
) -> SimulatedConfig:
    """sitl_short with the firmware's landing tuning, the moving pad's EKF and the no-release-off-
    the-pad policy, the pad driving off at ``speed_m_s`` on the seed's course."""
    if autopilot not in REAL_AUTOPILOTS:
        raise ValueError(f"autopilot {autopilot!r}: expected one of {REAL_AUTOPILOTS}")
    tuning = firmware_tuning(autopilot)
    ready = {"ready_timeout_s": 120.0} if autopilot == "ardupilot" else {}
    overrides: dict[str, Any] = {
        "autopilot": autopilot,
        "connection": connection,
        "mission": {**tuning["mission"], **ready, "return_home": False},
        "landing": {
            **tuning["landing"],
            "fusion": True,
            "moving_pad": {"enabled": True},
            "policy": {"require_pad_lock": True},
        },
        "sim": {
            "seed": seed,
            "pad_motion": {"speed_m_s": speed_m_s, "course_deg": moving_pad_course_deg(seed), "start_s": start_s},
        },
    }
    return load_simulated_config(shipped_params_path("sitl_short.toml"), overrides=overrides)


async def fly_moving_pad(
    autopilot: str,
    log_dir: Path,
    seed: int,
    speed_m_s: float = 2.0,
    start_s: float = MOVING_PAD_START_S,
    root: Path | None = None,
) -> dict[str, Any]:
    """One delivery onto the moving pad on a fresh SITL; the landing scored on truth."""
    t0 = time.monotonic()
    async with real_vehicle(autopilot, log_dir, MOVING_PAD_BOOT_PARAMS[autopilot], root=root) as rv:
        config = moving_pad_config(autopilot, rv.connection, seed, speed_m_s, start_s)
        ap = rv.backend(config)
        try:
            await ap.connect(timeout_s=20.0)
            standing = true_pad_ne(config, rv.truth.origin, (0.0, 0.0))
            r = await fly_on_truth(
                config, ap, rv.truth, rv.truth.origin, (0.0, 0.0), timeout_s=LANDING_TIMEOUT_S[autopilot]
            )
        finally:
            await ap.close()
    # the descent tick by tick, truth relative to the pad where it is (LANDING_TRACE_FIELDS)
    _write_trace(log_dir / "landing_trace.csv", r.landing_trace)
    half = config.mission.pad.size_m / 2.0
    dn = r.touchdown_truth_ne_m[0] - r.true_pad_ne_m[0]
    de = r.touchdown_truth_ne_m[1] - r.true_pad_ne_m[1]
    on_pad = bool(math.isfinite(dn) and abs(dn) <= half and abs(de) <= half)
    return {
        "seed": seed,
        "course_deg": config.sim.pad_motion.course_deg,
        "error_m": r.pad_landing_error_m,
        "contact_error_m": r.contact_error_m,  # at the ground contact (the pad stopped there)
        "on_pad": on_pad,
        "released": r.releases > 0 and r.delivered,
        "failure": r.failure,
        # how far the pad drove before it stopped at the contact (nan: it never stopped)
        "pad_moved_m": math.hypot(r.pad_stop_ne_m[0] - standing[0], r.pad_stop_ne_m[1] - standing[1]),
        "pad_stop_s": r.pad_stop_s,  # from the take-off: the ground contact
        "touchdown_s": r.touchdown_s,  # from the take-off: the autopilot's landed state
        "markers_used": r.markers_used,
        "uwb_used": r.uwb_used,
        "wall_s": time.monotonic() - t0,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--firmware", choices=REAL_AUTOPILOTS, required=True)
    ap.add_argument("--seed", type=int, default=200100, help="the first draw's seed")
    ap.add_argument("--n", type=int, default=4, help="draws (seeds seed, seed + 1, ...)")
    ap.add_argument("--speed", type=float, default=2.0, help="the pad's speed, m/s")
    ap.add_argument("--out", type=Path, default=None, help="log folder (default runs/moving-pad-<firmware>-<time>)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    out = args.out or Path("runs") / time.strftime(f"moving-pad-{args.firmware}-%Y%m%d-%H%M%S")
    rows = []
    for k in range(args.n):
        seed = args.seed + k
        row = asyncio.run(fly_moving_pad(args.firmware, out / str(seed), seed, args.speed))
        rows.append(row)
        print(
            f"| {seed} | {row['course_deg']:.0f} deg | {100 * row['error_m']:.1f} cm | "
            f"{100 * row['contact_error_m']:.1f} cm | "
            f"{'yes' if row['on_pad'] else 'no'} | {'yes' if row['released'] else 'no'} | "
            f"{row['pad_stop_s']:.1f} s | {row['touchdown_s']:.1f} s | {row['wall_s']:.0f} s | {row['failure']} |",
            flush=True,
        )
    errs = [r["error_m"] for r in rows if math.isfinite(r["error_m"])]
    if errs:
        print(
            f"mean {100 * sum(errs) / len(errs):.1f} cm, max {100 * max(errs):.1f} cm, "
            f"on the pad {sum(r['on_pad'] for r in rows)} of {len(rows)}, "
            f"released {sum(r['released'] for r in rows)} of {len(rows)}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
