"""``python -m companion_firmware.hang_on_signal HANG_S [companion arguments]``: the ``companion``
command line, with a SIGUSR1 handler that blocks the main thread, the one the event loop runs on,
in ``time.sleep(HANG_S)``: a hung control loop (a blocking call, a stuck driver) while every other
thread of the process (the autopilot link's, MAVSDK's, the watchdog's) goes on. Python runs a
signal handler on the main thread, so the sleep is the loop's own; nothing of the companion is
patched. Used by firmware/companion_kill.py (``fly_and_stop(..., how="hang")``)."""

from __future__ import annotations

import runpy
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
    # `python -m companion ARGS` itself, run in this process (the harness sits beside the command
    # line, not on top of it: it imports none of it)
    sys.argv = ["companion", *argv[1:]]
    try:
        runpy.run_module("companion", run_name="__main__", alter_sys=True)
    except SystemExit as done:
        return done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
