"""Exit codes of the ``companion`` command line (the table in docs/flying.md) and the
start-up error that carries one.

A start-up failure ends the process with one line on stderr, ``companion COMMAND: what failed;
the setting to change``, and one of these codes; nothing is left running.
"""

from __future__ import annotations

OK = 0
#: the command ran but its result is a failure: mission not delivered, a check found problems,
#: a replay differs
FAILED = 1
#: bad input: command-line usage (argparse exits 2 too), a parameter file, key or value
BAD_INPUT = 2
#: the autopilot link could not be opened (refused, unusable address) or no autopilot answered
#: within ``runtime.connect_timeout_s``
AUTOPILOT_UNREACHABLE = 3
#: a device is missing: the autopilot's serial port, the camera, the UWB tag's port
DEVICE_MISSING = 4
#: the Zenoh telemetry session could not be opened (endpoint in use, no router)
TELEMETRY_UNAVAILABLE = 5
#: the pre-flight check found the vehicle configured wrong (``companion preflight``, and ``companion
#: fly`` before it arms): a parameter to set, a sensor or a clock out of line
PREFLIGHT_FAILED = 6
#: the Dask cluster of ``campaign landing --cluster`` could not be used: no scheduler answered, it
#: has no worker, or a worker runs another environment (code, Python, numeric libraries)
CLUSTER_UNAVAILABLE = 7
#: Ctrl-C before the command finished
INTERRUPTED = 130


class StartupError(Exception):
    """A command could not start; ``str(err)`` is the one line naming what failed and the setting
    to change, ``code`` the exit code."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def link_startup_error(err: Exception, where: str, connect_timeout_s: float) -> StartupError:
    """The one line for an autopilot link that could not be used at start-up (``fly``,
    ``preflight``): a missing device (exit 4) or no answer / refused (exit 3). ``where``: the
    parameter file the connection comes from, as the commands name it."""
    from companion.autopilot.interface import LinkDeviceMissing

    if isinstance(err, LinkDeviceMissing):
        return StartupError(f"{err}; plug the autopilot in or change connection {where}", DEVICE_MISSING)
    return StartupError(
        f"{err}; check the autopilot is on and sending there, or change connection {where} "
        f"(runtime.connect_timeout_s = {connect_timeout_s:g} s)",
        AUTOPILOT_UNREACHABLE,
    )
