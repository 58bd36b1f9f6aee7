"""``companion campaign``: landing campaigns (embedded simulator or real SITL), parity, firmware probe."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from typing import Any

from companion.cli import exits
from companion.cli.args import RESULTS_MIN_BYTES, Once, output_folder, positive_int
from companion.units import format_cm

log = logging.getLogger(__name__)


def _landing_args_refused(args: argparse.Namespace) -> str | None:
    """Why these landing-campaign options cannot go together, or None."""
    if args.cluster and (args.autopilot or args.jobs is not None):
        other = "--autopilot" if args.autopilot else "--jobs"
        return f"--cluster and {other} exclude each other"
    if args.weather and args.autopilot != "ardupilot" and args.profile != "arducopter-sitl":
        return (
            "--weather needs --autopilot ardupilot or --profile arducopter-sitl "
            "(the embedded ideal profile flies the drawn weather anyway; PX4 SIH has no wind)"
        )
    return None


def _landing_variants(args: argparse.Namespace) -> list[str]:
    from companion_lab.landing_campaign import FAILURE_VARIANTS

    variants = ["fusion", "gps_only"] + (list(FAILURE_VARIANTS) if args.failures else [])
    if args.variants:
        variants = _named_variants(args.variants)
    return variants


def _named_variants(text: str) -> list[str]:
    """The comma-separated --variants, each a known one: else StartupError (one line, exit 2)."""
    from companion_lab.campaign_landing import VARIANTS

    variants = [v.strip() for v in text.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown or not variants:
        known = ", ".join(sorted(VARIANTS))
        what = ", ".join(unknown) or "(none given)"
        raise exits.StartupError(f"--variants {text!r}: unknown {what}; choose from {known}", exits.BAD_INPUT)
    return variants


def _fly_landing_campaign(
    args: argparse.Namespace, variants: list[str], out: Any, on_progress: Any, progress: Any
) -> dict[str, Any] | int:
    """The campaign's result, or the exit code of a campaign that could not run."""
    from companion_lab.campaign_cluster import (
        ClusterAddressError,
        ClusterError,
    )  # Dask itself is imported only with --cluster
    from companion_lab.campaign_landing import CampaignLandingError
    from companion_lab.landing_campaign import run_landing_campaign, usable_cpus

    jobs = args.jobs if args.jobs is not None else usable_cpus()
    if args.autopilot:
        from companion_lab.real_campaign import run_real_landing_campaign

        return run_real_landing_campaign(
            args.autopilot,
            args.n,
            args.seed,
            tuple(variants),
            args.params,
            out / "sitl",
            on_progress,
            weather=args.weather,
        )
    from companion_lab.real_campaign import FIRMWARE_OF_PROFILE, firmware_tuning

    # a firmware's profile flies with the landing tuning shipped for that firmware
    fw = FIRMWARE_OF_PROFILE.get(args.profile)
    tuning = firmware_tuning(fw) if fw else None
    if args.weather and tuning is not None:
        tuning["sim"] = {"profile_weather": True}
    try:
        return run_landing_campaign(
            args.n,
            args.seed,
            tuple(variants),
            args.params,
            on_progress,
            profile=args.profile,
            tuning=tuning,
            jobs=jobs,
            cluster=args.cluster,
        )
    except CampaignLandingError as err:
        progress.stop()
        log.debug("the failed landing", exc_info=err)
        print(f"companion campaign landing: {err}", file=sys.stderr)
        return exits.FAILED
    except ClusterError as err:
        progress.stop()
        print(f"companion campaign landing: {err}", file=sys.stderr)
        return exits.BAD_INPUT if isinstance(err, ClusterAddressError) else exits.CLUSTER_UNAVAILABLE


def _print_landing_summary(console: Any, args: argparse.Namespace, result: dict[str, Any]) -> None:
    from rich.table import Table

    where = f"real {args.autopilot} SITL" if args.autopilot else f"embedded simulator, {args.profile} profile"
    table = Table(title=f"{args.n} landings per variant, seed {args.seed}, {where} (true touchdown vs true pad centre)")
    columns = ("variant", "landed", "mean", "median", "p90", "p95", "max", "on the pad", "released", "home w/ parcel")
    for col in (*columns, "failed"):
        table.add_column(col, justify="right" if col != "variant" else "left")
    for v, s in result["summary"].items():
        table.add_row(
            v,
            f"{s['landed']} of {s['n']}",
            *(format_cm(s[k]) for k in ("mean_m", "median_m", "p90_m", "p95_m", "max_m")),
            f"{s['on_pad_pct']:.0f} %",
            f"{s['released']} of {s['n']}",
            f"{s['home_with_parcel']} of {s['n']}",
            f"{s['failed']} of {s['n']}",
        )
    console.print(table)
    for v, s in result["summary"].items():
        if "heading_mean_deg" in s:  # a pad with a heading (docs/pad-heading.md)
            console.print(
                f"{v}: heading error at touchdown mean {s['heading_mean_deg']:.2f} deg, p90 "
                f"{s['heading_p90_deg']:.2f} deg, max {s['heading_max_deg']:.2f} deg, within 3 deg "
                f"{s['heading_within_3deg_pct']:.0f} %"
            )


def _landing_exit(result: dict[str, Any], out: Any) -> int:
    for line in result.get("lost", []):
        print(f"companion campaign landing: {line}", file=sys.stderr)
    failed = {v: s["failed"] for v, s in result["summary"].items() if s["failed"]}
    if failed:
        # every landing counts: one that neither released nor brought the parcel home is a failure
        print(
            "companion campaign landing: failed landings (no touchdown, a crash or a failed mission): "
            + ", ".join(f"{v} {k} of {result['summary'][v]['n']}" for v, k in failed.items())
            + f"; each one's 'failure' is in {out / 'landing_campaign.json'}",
            file=sys.stderr,
        )
        return exits.FAILED
    return 0


def cmd_campaign_landing(args: argparse.Namespace) -> int:
    if args.faults:  # the fault campaign (docs/companion-death.md)
        from companion.cli.campaign_faults import cmd_campaign_faults

        return cmd_campaign_faults(args)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from companion.cli.console import make_console
    from companion_lab.campaign_output import write_outputs

    refused = _landing_args_refused(args)
    if refused:
        print(f"companion campaign landing: {refused}", file=sys.stderr)
        return exits.BAD_INPUT
    variants = _landing_variants(args)
    console = make_console()
    with Progress(
        TextColumn("{task.description:<12}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        disable=args.quiet,
    ) as progress:
        task = progress.add_task("landing", total=args.n * len(variants))

        def on_progress(variant: str, done: int, total: int) -> None:
            progress.update(task, description=variant, completed=done)

        out = output_folder(args.out, time.strftime("landing-%Y%m%d-%H%M%S"), RESULTS_MIN_BYTES)
        result = _fly_landing_campaign(args, variants, out, on_progress, progress)
        if isinstance(result, int):
            return result
    files = write_outputs(result, out)
    _print_landing_summary(console, args, result)
    console.print(f"written: {', '.join(str(f) for f in files)}")
    return _landing_exit(result, out)


def cmd_campaign_parity(args: argparse.Namespace) -> int:
    from rich.table import Table

    from companion.cli.console import make_console
    from companion_lab.real_campaign import run_parity

    variants = tuple(_named_variants(args.variants))
    if args.weather and args.autopilot != "ardupilot":
        print("companion campaign parity: --weather needs --autopilot ardupilot (PX4 SIH has no wind)", file=sys.stderr)
        return exits.BAD_INPUT
    # a named folder is probed now (read-only, full: exit 2); the default one is made by run_parity
    out = output_folder(args.out, "", RESULTS_MIN_BYTES) if args.out else None
    result = run_parity(args.autopilot, args.n, args.seed, args.params, out, variants, weather=args.weather)
    console = make_console()
    for v, c in result["comparison"].items():
        title = f"{v}: {result['profile']} profile vs real {args.autopilot} SITL, same {len(c['seeds'])} draws"
        table = Table(title=title)
        for col in ("", "mean", "p90", "max"):
            table.add_column(col, justify="right" if col else "left")
        for name in ("predicted", "real"):
            f = c[name]
            table.add_row(name, *(format_cm(f[k]) for k in ("mean_m", "p90_m", "max_m")))
        r = c["ratio_predicted_to_real"]
        table.add_row("predicted/real", *(f"{r[k]:.2f}" for k in ("mean_m", "p90_m", "max_m")))
        console.print(table)
        console.print(
            f"mean and p90 within {c['within_factor']}x: {'yes' if c['mean_and_p90_within_factor'] else 'NO'}; "
            f"failure classes agree: {'yes' if c['failure_classes_agree'] else 'NO'} "
            f"(disagreeing seeds: {c['failure_class_disagreements'] or 'none'})"
        )
    console.print(f"written: {result['out_dir']}/parity.json, parity.png")
    agree = all(c["mean_and_p90_within_factor"] and c["failure_classes_agree"] for c in result["comparison"].values())
    return 0 if agree else exits.FAILED


def cmd_campaign_probe(args: argparse.Namespace) -> int:
    from companion_lab.firmware_probe import run_probe

    out = output_folder(args.out, time.strftime(f"probe-{args.autopilot}-%Y%m%d-%H%M%S"), RESULTS_MIN_BYTES)
    fig = run_probe(args.autopilot, out)
    for k, v in sorted(fig.items()):
        print(f"{k:48s} {json.dumps(v)}")
    print(f"written: {out}/probe.csv, {out}/probe.json")
    return 0


def register_campaign(csub: Any) -> None:
    """Add ``companion campaign landing``."""
    cl = csub.add_parser("landing", help="Monte Carlo precision landings: fusion vs GPS-only (delivery Fig. 15)")
    cl.add_argument("--n", type=positive_int, default=100, help="landings per variant")
    cl.add_argument("--seed", type=int, default=1, help="seed of the draws")
    cl.add_argument(
        "--failures",
        action="store_true",
        help="also: no_camera, no_uwb, outer_only, inner_only, sensors_failed, camera_blind_5m, pad_4m, pad_4m_search, "
        "pad_missing_alternate",
    )
    cl.add_argument(
        "--variants",
        help="comma-separated variants, overrides --failures (default: fusion,gps_only, and the failure "
        "variants with --failures)",
    )
    cl.add_argument("--params", action=Once, help="scenario parameters (default: the shipped landing_campaign.toml)")
    cl.add_argument("--out", help="output folder (default runs/landing-<time>)")
    cl.add_argument("--quiet", action="store_true", help="no progress bar")
    cl.add_argument(
        "--jobs",
        type=positive_int,
        help="embedded landings flown at once, each in a worker process (default: the CPUs this process may "
        "use; 1: one after the other in this process); the results are the same whatever the number",
    )
    cl.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="fly the embedded landings on the Dask cluster whose scheduler is at ADDRESS (tcp://HOST:PORT; "
        "its workers need this commit: pip install -e '.[cluster]'); the same results as --jobs "
        "(default: worker processes on this machine, --jobs)",
    )
    where = cl.add_mutually_exclusive_group()
    where.add_argument(
        "--profile",
        choices=("ideal", "px4-sih", "arducopter-sitl"),
        default="ideal",
        help="embedded simulator behaving like this autopilot (measured on its SITL; default ideal)",
    )
    where.add_argument(
        "--autopilot",
        choices=("px4", "ardupilot"),
        help="fly the landings on the real SITL build (PX4_DIR / ARDUPILOT_DIR), in real time "
        "(default: the embedded simulator)",
    )
    cl.add_argument(
        "--weather",
        action="store_true",
        help="gusts, GPS error and sensor noise from the embedded campaign's distributions, driven on the real "
        "ArduCopter SITL (--autopilot ardupilot) or kept by the arducopter-sitl profile (docs/weather.md)",
    )
    cl.add_argument(
        "--faults",
        metavar="LIST",
        help="a fault campaign instead: comma-separated faults (stall_1s, stall_3s, stall_15s, link_cut, "
        "forged_command, or all), --n landings each on the MAVLink sim vehicle in real time, the dialect "
        "and the moment drawn from --seed (docs/companion-death.md); default params sitl_short.toml",
    )
    cl.set_defaults(func=cmd_campaign_landing)
    cp = csub.add_parser(
        "parity",
        help="the embedded campaign with the firmware's profile against the real SITL on the same draws",
    )
    cp.add_argument("--autopilot", choices=("px4", "ardupilot"), required=True, help="the real SITL to compare with")
    cp.add_argument("--n", type=positive_int, default=10, help="landings (each real one takes about a minute)")
    cp.add_argument("--seed", type=int, default=1, help="seed of the draws")
    cp.add_argument("--variants", default="fusion", help="comma-separated variants (default fusion)")
    cp.add_argument("--params", action=Once, help="scenario parameters (default: the shipped landing_campaign.toml)")
    cp.add_argument("--out", help="output folder (default runs/parity-<autopilot>-<time>)")
    cp.add_argument("--weather", action="store_true", help="both sides fly the drawn weather (docs/weather.md)")
    cp.set_defaults(func=cmd_campaign_parity)
    pr = csub.add_parser(
        "probe",
        help="measure a real SITL for its autopilot profile: estimate errors, velocity step, land detector",
    )
    pr.add_argument("--autopilot", choices=("px4", "ardupilot"), required=True, help="the real SITL to measure")
    pr.add_argument("--out", help="output folder (default runs/probe-<autopilot>-<time>)")
    pr.set_defaults(func=cmd_campaign_probe)
