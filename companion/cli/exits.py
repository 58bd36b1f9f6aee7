"""Exit codes of the ``companion`` command line (the table in docs/flying.md) and the
start-up error that carries one.

A start-up failure ends the process with one line on stderr, ``companion COMMAND: what failed;
the setting to change``, and one of these codes; nothing is left running.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from companion.config import CompanionConfig

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
#: the flight ended (``fly`` delivered, ``demo`` done) but its logs are incomplete: a full disk or
#: an I/O error stopped a log file, or rows were dropped (``companion.flightlog.losses``)
LOGS_INCOMPLETE = 8
#: Ctrl-C before the command finished
INTERRUPTED = 130


def say_logs_incomplete(command: str, run_dir: Path) -> bool:
    """Print on stderr the one line naming what ``run_dir``'s logs lost in flight (a full disk,
    an I/O error: ``companion.flightlog.losses``); True when they lost anything (exit
    :data:`LOGS_INCOMPLETE` if the flight otherwise succeeded)."""
    from companion.flightlog.losses import describe

    lost = describe(run_dir)
    if lost:
        print(f"companion {command}: {lost}: {run_dir} holds the flight up to where they stopped", file=sys.stderr)
    return bool(lost)


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


@contextlib.contextmanager
def flight_startup_errors(
    where: str, params_file: str, config: CompanionConfig, telemetry_optional: bool = True
) -> Iterator[None]:
    """The one line and exit code for each way a flight's start can fail once the autopilot link
    is being opened (``fly`` and ``fly --orders``). ``where``: the parameter file the connection
    comes from, as the commands name it; ``telemetry_optional``: the hint may say to turn it off."""
    from companion.autopilot.interface import AutopilotUnreachable, ConnectionUrlError, LinkDeviceMissing
    from companion.autopilot.signing import SigningError, SigningKeyError
    from companion.delivery.autopilot_mission import MissionDownloadError, MissionPlanError
    from companion.delivery.shell import AbortedBeforeFlight
    from companion.telemetry.session import SessionOpenError

    try:
        yield
    except AbortedBeforeFlight as err:
        raise StartupError(f"{err}: nothing was commanded", INTERRUPTED) from None
    except MissionPlanError as err:  # mission.destination = "autopilot_mission" (docs/gcs.md)
        raise StartupError(
            f"{err}; upload a delivery plan from the GCS, or set mission.destination = 'params' in "
            f"{params_file}: nothing was armed",
            BAD_INPUT,
        ) from None
    except MissionDownloadError as err:
        raise StartupError(f"{err}: nothing was armed", AUTOPILOT_UNREACHABLE) from None
    except SigningKeyError as err:
        raise StartupError(f"{err}; fix signing.key_file {where}", BAD_INPUT) from None
    except SigningError as err:
        raise StartupError(str(err), AUTOPILOT_UNREACHABLE) from None
    except (AutopilotUnreachable, LinkDeviceMissing) as err:
        raise link_startup_error(err, where, config.runtime.connect_timeout_s) from None
    except ConnectionUrlError as err:
        raise StartupError(f"{err}; change connection {where}", BAD_INPUT) from None
    except SessionOpenError as err:
        off = ", or set telemetry.enabled = false" if telemetry_optional else ""
        raise StartupError(
            f"telemetry: {err}; change telemetry.zenoh_config (now {config.telemetry.zenoh_config!r}) "
            f"in {params_file}{off}",
            TELEMETRY_UNAVAILABLE,
        ) from None
