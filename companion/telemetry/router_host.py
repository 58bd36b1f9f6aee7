"""A bare Zenoh router in its own process, for the fleet benchmark (zenohd's role).

``python -m companion.telemetry.router_host tcp/127.0.0.1:7447`` opens a ``mode="router"``
session listening on the endpoint (no scouting), prints ``ready`` on stdout, then answers on
stdin: a line ``cpu`` is answered with this process's CPU time in seconds
(``time.process_time``, all its threads: Zenoh's runtime does the routing), end of input closes
the session and exits. Keeping the router out of the benchmark's process lets the benchmark
report the router's CPU per message apart from the vehicles' and the ground's.
"""

from __future__ import annotations

import sys
import time

from companion.telemetry.session import SettingsError, ZenohSettings


def router_settings(endpoint: str) -> ZenohSettings:
    """Router settings listening on ``endpoint`` only: no multicast or gossip scouting."""
    return ZenohSettings(
        mode="router",
        listen=(endpoint,),
        multicast_scouting=False,
        gossip_scouting=False,
        scouting_delay_ms=0,
    )


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        sys.stderr.write("usage: python -m companion.telemetry.router_host ENDPOINT (e.g. tcp/127.0.0.1:7447)\n")
        return 2
    try:
        settings = router_settings(args[0])
    except SettingsError as e:
        sys.stderr.write(f"router_host: {e}\n")
        return 2
    session = settings.open_or_explain()
    try:
        sys.stdout.write("ready\n")
        sys.stdout.flush()
        for line in sys.stdin:
            if line.strip() == "cpu":
                sys.stdout.write(f"{time.process_time():.6f}\n")
                sys.stdout.flush()
            elif line.strip():
                sys.stderr.write(f"router_host: unknown request {line.strip()!r} (expected 'cpu')\n")
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
