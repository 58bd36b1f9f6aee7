"""``companion plan``: QGroundControl plan files. ``plan check FILE.plan --params X`` says which
delivery a plan describes (or why it describes none); ``plan export --params X --out FILE.plan``
writes the parameters' delivery as a plan QGC opens (docs/gcs.md#qgroundcontrol-plan-files)."""

from __future__ import annotations

import argparse
import json
import logging
import math
from pathlib import Path
from typing import Any

from companion.cli import exits
from companion.cli.args import Once
from companion.cli.exits import StartupError
from companion.config import CompanionConfig, load_config
from companion.geometry.earth import GeoPoint

log = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("plan", help="QGroundControl .plan files: check one, or export the delivery as one")
    psub = p.add_subparsers(dest="plan_cmd", metavar="ACTION", required=True)
    pc = psub.add_parser("check", help="the delivery a plan file describes: pad, alternate pad, fence")
    pc.add_argument("file", help="the .plan file (QGroundControl's JSON)")
    pc.add_argument("--params", action=Once, required=True, help="parameter file the plan is flown with")
    pc.add_argument("--json", action="store_true", help="print the result as JSON")
    pc.set_defaults(func=cmd_plan_check)
    pe = psub.add_parser("export", help="write the parameters' delivery as a .plan QGroundControl opens")
    pe.add_argument("--params", action=Once, required=True, help="parameter file with the delivery")
    pe.add_argument("--out", required=True, help="the .plan file to write")
    pe.add_argument(
        "--home",
        metavar="LAT,LON,ALT",
        help="the home (takeoff point), degrees and metres AMSL (default: sim.home with autopilot = 'sim'; needed "
        "otherwise: a real home is only known in flight)",
    )
    pe.set_defaults(func=cmd_plan_export)


def _config(params: str) -> CompanionConfig:
    config = load_config(params)
    if config.autopilot == "sim":  # the simulator's own checks (its home, the fence around it)
        from companion_sitl.params import simulated_config_from_dict

        return simulated_config_from_dict(config.model_dump(), params)
    return config


def cmd_plan_check(args: argparse.Namespace) -> int:
    from companion.delivery.qgc_plan import PlanFileError, config_from_plan, read_plan

    config = _config(args.params)
    try:
        plan = read_plan(args.file)
        flown, said = config_from_plan(config, plan)
    except PlanFileError as err:
        raise StartupError(err.reason, exits.BAD_INPUT) from None
    m, f = flown.mission, flown.fence
    out = {
        "plan": args.file,
        "said": said,
        "pad": {"lat_deg": m.pad.lat_deg, "lon_deg": m.pad.lon_deg, "alt_amsl_m": m.pad.alt_amsl_m},
        "alternate_pad": (
            None
            if m.alternate_pad is None
            else {"lat_deg": m.alternate_pad.lat_deg, "lon_deg": m.alternate_pad.lon_deg}
        ),
        "fence": {"enabled": f.enabled, "inclusion": len(f.inclusion), "exclusion": len(f.exclusion)},
        "items": len(plan.items),
    }
    if args.json:
        print(json.dumps(out, indent=2))
        return exits.OK
    print(f"{args.file}: {said}")
    alt = "the home's ground" if m.pad.alt_amsl_m is None else f"{m.pad.alt_amsl_m:.1f} m AMSL"
    print(f"  pad            {m.pad.lat_deg:.7f}, {m.pad.lon_deg:.7f} at {alt}")
    if m.alternate_pad is not None:
        print(f"  alternate pad  {m.alternate_pad.lat_deg:.7f}, {m.alternate_pad.lon_deg:.7f}")
    fence = f"{len(f.inclusion)} inclusion, {len(f.exclusion)} exclusion polygon(s)" if f.enabled else "off"
    print(f"  fence          {fence}")
    items = len(plan.items)
    print(f"  flown at       {m.height_m:g} m above the pad ({items} plan items; the companion flies its own path)")
    return exits.OK


def parse_home(text: str) -> GeoPoint:
    parts = text.split(",")
    try:
        lat, lon, alt = (float(x) for x in parts) if len(parts) == 3 else (math.nan,) * 3
    except ValueError:
        lat = lon = alt = math.nan
    if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)) or abs(lat) > 90 or abs(lon) > 180:
        raise StartupError(
            f"--home {text!r}: expected LAT,LON,ALT (degrees within +-90 / +-180, metres AMSL)", exits.BAD_INPUT
        )
    return GeoPoint(lat, lon, alt)


def cmd_plan_export(args: argparse.Namespace) -> int:
    from companion.delivery.qgc_plan import export_plan

    config = _config(args.params)
    if args.home:
        home = parse_home(args.home)
    elif config.autopilot == "sim":
        h = config.sim.home  # type: ignore[attr-defined]  # a SimulatedConfig's (see _config)
        home = GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m)
    else:
        raise StartupError(
            f"autopilot = {config.autopilot!r} in {args.params}: give --home LAT,LON,ALT (a real home is only known "
            "in flight)",
            exits.BAD_INPUT,
        )
    plan = export_plan(config, home)
    out = Path(args.out)
    try:
        out.write_text(json.dumps(plan, indent=4) + "\n", encoding="utf-8")
    except OSError as err:
        raise StartupError(f"--out {out}: cannot write: {err.strerror or err}", exits.BAD_INPUT) from None
    n_items, n_polys = len(plan["mission"]["items"]), len(plan["geoFence"]["polygons"])
    print(f"wrote {out}: {n_items} mission items, {n_polys} fence polygons")
    return exits.OK
