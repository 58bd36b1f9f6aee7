"""``companion bench dropzone``: the drop-zone check's figures over seeded rendered descents
(companion_lab.bench.drop_zone, docs/drop-zone.md)."""

from __future__ import annotations

import argparse
import json
import logging
from typing import Any

from companion.cli import exits
from companion.cli.args import positive_int
from companion.cli.exits import StartupError

log = logging.getLogger(__name__)

SCENARIO_TITLES = {
    "none": "clear pad",
    "box": "box on the pad",
    "person": "person walking into the margin",
    "shadow": "shadow across the pad (no object)",
}


def _s(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f} s"


def format_drop_zone(r: dict[str, Any]) -> str:
    """The bench's result as a table: holds per scenario (false on a clear pad and under the
    shadow, caught for the box and the person) and the time to decide."""
    which = f"draws {','.join(map(str, r['only']))}" if "only" in r else f"{r['draws']} seeded draws"
    lines = [
        f"bench dropzone: {which} per scenario (seed {r['seed']}), a rendered hover at 10 m "
        f"then a descent to 1.5 m, the check at {r['fps']:g} frames/s",
        f"  {'scenario':<34} {'held':>9} {'median':>8} {'p90':>8} {'max':>8} {'ms/frame':>9}",
    ]
    for kind, s in r["scenarios"].items():
        held = f"{s['holds']}/{r['draws']}"
        lines.append(
            f"  {SCENARIO_TITLES.get(kind, kind):<34} {held:>9} {_s(s['median_time_to_decide_s']):>8} "
            f"{_s(s['p90_time_to_decide_s']):>8} {_s(s['max_time_to_decide_s']):>8} {s['check_ms_per_frame']:>9.1f}"
        )
    lines.append(
        "  held: false holds for the clear pad and the shadow (goal 0 %), occluders caught for the box and the "
        "person (goal >= 99 %); time to decide: from the first judged frame (box) or the person entering the margin"
    )
    return "\n".join(lines)


def cmd_bench_dropzone(args: argparse.Namespace) -> int:
    from companion_lab.bench.drop_zone import SCENARIOS, bench_drop_zone

    scenarios = tuple(args.scenarios.split(",")) if args.scenarios else SCENARIOS
    bad = [s for s in scenarios if s not in SCENARIOS]
    if bad:
        raise StartupError(
            f"--scenarios {args.scenarios}: unknown {bad}; expected some of {','.join(SCENARIOS)}", exits.BAD_INPUT
        )
    if not 1.0 <= args.fps <= 60.0:
        raise StartupError(f"--fps {args.fps}: must be 1-60", exits.BAD_INPUT)
    only = None
    if args.draw:
        try:
            only = [int(d) for d in args.draw.split(",")]
        except ValueError:
            raise StartupError(f"--draw {args.draw}: expected comma-separated draw numbers", exits.BAD_INPUT) from None
        bad_d = [d for d in only if not 0 <= d < args.draws]
        if bad_d:
            raise StartupError(f"--draw {args.draw}: {bad_d} not in 0-{args.draws - 1}", exits.BAD_INPUT)
    r = bench_drop_zone(args.draws, args.seed, args.fps, scenarios, only=only)  # type: ignore[arg-type]
    print(json.dumps(r, indent=2) if args.json else format_drop_zone(r))
    return exits.OK


def register_bench_dropzone(bsub: Any) -> None:
    """Add ``companion bench dropzone``."""
    bd = bsub.add_parser(
        "dropzone",
        help="the drop-zone check over seeded rendered descents: false holds on a clear pad, occluders caught, "
        "time to decide",
    )
    bd.add_argument("--draws", type=positive_int, default=100, help="seeded draws per scenario")
    bd.add_argument("--seed", type=int, default=0, help="seed of the draws")
    bd.add_argument("--fps", type=float, default=10.0, help="frames a second the check judges")
    bd.add_argument("--scenarios", help="comma-separated subset of none,box,person,shadow (default: all)")
    bd.add_argument(
        "--draw",
        help="comma-separated draws of the --draws to run alone, on the same trajectories (e.g. 7,35,65; default: all)",
    )
    bd.add_argument("--json", action="store_true", help="print the results as JSON")
    bd.set_defaults(func=cmd_bench_dropzone)
