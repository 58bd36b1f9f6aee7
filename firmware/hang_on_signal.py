"""``python -m companion_firmware.hang_on_signal HANG_S [companion arguments]``: the ``companion``
command line, with a SIGUSR1 handler that blocks the main thread, the one the event loop runs on,
in ``time.sleep(HANG_S)``: a hung control loop (a blocking call, a stuck driver) while every other
thread of the process (the autopilot link's, MAVSDK's, the watchdog's) goes on. Python runs a
signal handler on the main thread, so the sleep is the loop's own; nothing of the companion is
patched. Used by firmware/companion_kill.py (``fly_and_stop(..., how="hang")``)."""

from __future__ import annotations

import signal
import sys
import time


def main(argv: list[str]) -> int:
    if not argv:
        print("usage: python -m companion_firmware.hang_on_signal HANG_S [companion arguments]", file=sys.stderr)
        return 2
    hang_s = float(argv[0])

    def hang(signum: int, frame: object) -> None:
        time.sleep(hang_s)

    signal.signal(signal.SIGUSR1, hang)
    from companion.cli.main import main as companion_main

    return companion_main(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
