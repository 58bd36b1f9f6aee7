"""A landing campaign's landings flown on a Dask distributed cluster
(``companion campaign landing --cluster tcp://HOST:PORT``).

Each landing depends on its draw alone (:func:`companion_lab.campaign_landing.fly_landing`), so
the scheduler may hand it to any worker; the rows are put back in the campaign's order, and the
result is the local pool's, bit for bit, provided every worker computes as this process does. So
each worker's environment (a hash of this project's installed code, Python, the numeric
libraries' versions and the SIMD paths they take on its CPU) is compared with this process's
before the campaign starts and again with every landing (a worker may join later); a worker that
differs is refused by name. The parameter file travels with each landing: a worker flies the
file this process read, not whatever lies at that path on its machine.

A worker that dies mid-landing is the scheduler's to handle: it hands the landing to another
worker, up to its ``distributed.scheduler.allowed-failures`` times (default 3); beyond that the
landing is counted as a failed, unflown landing and named (index, seed, variant, the last worker)
in the result's ``lost``: never dropped. A landing that raises ends the campaign naming it, as in
the local pool (the same draw raises again wherever it flies, so it is not retried).
"""

from __future__ import annotations

import asyncio
import hashlib
import importlib
import logging
import os
import pickle
import platform
import tempfile
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path
from typing import Any

from companion_lab.campaign_landing import CampaignLandingError, LandingTask, fly_landing, renders_camera, unflown_row

log = logging.getLogger(__name__)

#: how long the scheduler has to answer, and then to have at least one worker
CONNECT_TIMEOUT_S = 10.0

# the packages a landing runs (their code is hashed) and the libraries whose version or SIMD path
# can change a float
_PACKAGES = ("companion", "companion_sitl", "companion_lab", "companion_params")
_LIBRARIES = ("numpy", "scipy", "cv2", "filterpy", "pydantic")


class ClusterError(RuntimeError):
    """The cluster cannot fly the campaign: no scheduler at the address, no worker, or a worker
    whose environment differs from this process's (the message names it)."""


@cache
def environment() -> dict[str, str]:
    """What a landing's result depends on besides its draw, in this process: this project's
    code (a hash of its installed sources and parameter files), Python, the numeric libraries'
    versions, and the SIMD features numpy and OpenCV dispatch to on this CPU."""
    code = hashlib.sha256()
    for name in _PACKAGES:
        root = Path(importlib.import_module(name).__file__ or "").parent
        for p in sorted(root.rglob("*")):
            if p.suffix in (".py", ".toml") and "__pycache__" not in p.parts and p.is_file():
                code.update(f"{name}/{p.relative_to(root).as_posix()}\0".encode())
                code.update(p.read_bytes())
    env = {
        "code": code.hexdigest()[:16],
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
    for lib in _LIBRARIES:
        env[lib] = str(getattr(importlib.import_module(lib), "__version__", "?"))
    try:  # numpy's dispatched SIMD loops (numpy 2; numpy 1 names the module numpy.core)
        umath = importlib.import_module("numpy._core._multiarray_umath")
    except ImportError:
        umath = importlib.import_module("numpy.core._multiarray_umath")
    features = getattr(umath, "__cpu_features__", {})
    env["numpy SIMD"] = " ".join(f for f in getattr(umath, "__cpu_dispatch__", ()) if features.get(f))
    import cv2

    env["cv2 SIMD"] = cv2.getCPUFeaturesLine()
    return env


def _differences(mine: dict[str, str], theirs: dict[str, str]) -> str:
    keys = [k for k in sorted(set(mine) | set(theirs)) if mine.get(k) != theirs.get(k)]
    return "; ".join(f"{k} {theirs.get(k, 'absent')!r} (here {mine.get(k, 'absent')!r})" for k in keys)


@dataclass(frozen=True)
class ClusterLanding:
    """A landing as shipped to a worker: the task, its parameter file's name and text, and the
    environment the worker must have."""

    task: LandingTask
    params_name: str
    params_text: str
    environment: dict[str, str]


@dataclass(frozen=True)
class _FlownWhenLoaded:
    """A landing whose unpickling flies it on the worker (``fly_on_worker(landing)``). The task
    Dask runs is ``pickle.loads(bytes)``, which every worker can load: one that cannot import this
    project then fails the task, and is named, instead of dropping its connection to the scheduler
    (what a worker does when it cannot unpickle a task; the landing would count as killing it)."""

    landing: ClusterLanding

    def __reduce__(self) -> tuple[Any, tuple[ClusterLanding]]:
        return fly_on_worker, (self.landing,)


def _params_file(name: str, text: str) -> Path:
    """The parameter file on this worker's machine (one per content; written atomically, as
    several worker processes of a machine may write it at once)."""
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / "companion-campaign-params" / digest
    path = folder / name
    if not path.exists():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{name}.{os.getpid()}"
        tmp.write_text(text)
        os.replace(tmp, path)
    return path


def fly_on_worker(landing: ClusterLanding) -> tuple[str, Any]:
    """Run on a worker: ``("row", row)``; ``("raised", message)`` when the landing raised;
    ``("refused", (worker, environment))`` when this worker's environment differs."""
    from distributed import get_worker

    env = environment()
    if env != landing.environment:
        return "refused", (get_worker().address, env)
    task = replace(landing.task, base=_params_file(landing.params_name, landing.params_text))
    try:
        return "row", fly_landing(task)
    except Exception as err:
        return "raised", f"failed on worker {get_worker().address}: {type(err).__name__}: {err}"


def _what(err: BaseException) -> str:
    # Dask hands back what a worker could not deserialize as a bare Exception holding its repr
    return str(err) if type(err) is Exception else f"{type(err).__name__}: {err}"


def _refused(worker: str, theirs: dict[str, str]) -> ClusterError:
    return ClusterError(
        f"worker {worker} runs a different environment: {_differences(environment(), theirs)}; "
        "every worker needs `pip install -e '.[cluster]'` of this commit (and a restart since), "
        "with the same dependencies"
    )


class ClusterAddressError(ClusterError, ValueError):
    """The scheduler's address is not one (scheme, host or port)."""


async def _probe(address: str, timeout_s: float) -> None:
    from distributed.comm import connect

    comm = await connect(address, timeout=timeout_s)
    await comm.close()


def _connect(address: str, timeout_s: float) -> Any:
    try:
        from distributed import Client
        from distributed.comm.addressing import parse_address, parse_host_port
        from distributed.comm.registry import get_backend
    except ImportError:
        raise ClusterError("--cluster needs Dask distributed: pip install -e '.[cluster]'") from None
    try:
        scheme, location = parse_address(address)
        get_backend(scheme)  # a scheme Dask speaks
        if scheme in ("tcp", "tls", "ws", "wss"):
            parse_host_port(location)
    except ValueError as err:
        raise ClusterAddressError(f"{address!r} is not a Dask scheduler's address (tcp://HOST:PORT): {err}") from None
    # the scheduler is reached once by hand first: a Client that fails in its constructor is left
    # half-made (its close at the interpreter's exit prints a traceback after twice its timeout),
    # and a reply that is not Dask's protocol is told apart from no reply
    try:
        asyncio.run(_probe(address, timeout_s))
    except (OSError, TimeoutError) as err:
        raise ClusterError(f"no Dask scheduler answered at {address} within {timeout_s:g} s ({err})") from None
    except Exception as err:  # something answered, not in Dask's protocol
        raise ClusterError(f"what answers at {address} is not a Dask scheduler ({_what(err)})") from None
    try:
        client = Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as err:
        raise ClusterError(f"the Dask scheduler at {address} did not take this client ({_what(err)})") from None
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except (OSError, TimeoutError) as err:
        client.close()
        raise ClusterError(
            f"the scheduler at {address} has no worker after {timeout_s:g} s; start one: dask worker {address}"
        ) from err
    return client


def _worker_environment() -> dict[str, str]:
    """Run on a worker (by reference: the worker imports this module, or fails to)."""
    return environment()


def _erred_on(client: Any, key: str) -> str:
    """The worker(s) where the task ``key`` failed, as the scheduler recorded them."""

    def erred_on(dask_scheduler: Any) -> list[str]:
        ts = dask_scheduler.tasks.get(key)
        return sorted(ts.erred_on) if ts is not None and ts.erred_on else []

    try:
        return ", ".join(client.run_on_scheduler(erred_on)) or "(unknown)"
    except Exception as err:  # the scheduler may refuse to run code; the error is what matters
        log.debug("which worker failed %s: %s", key, err)
        return "(unknown)"


def _check_workers(client: Any) -> None:
    """Refuse the campaign when a worker cannot import this project or runs another environment."""
    mine = environment()
    for worker, theirs in sorted(client.run(_worker_environment, on_error="return").items()):
        if isinstance(theirs, BaseException):
            raise ClusterError(
                f"worker {worker} cannot run the campaign: {_what(theirs)}; "
                "every worker needs `pip install -e '.[cluster]'` of this commit"
            )
        if theirs != mine:
            raise _refused(worker, theirs)


def fly_on_cluster(
    tasks: list[LandingTask],
    address: str,
    finished: Callable[[LandingTask, dict[str, Any], int], None],
    timeout_s: float | None = None,
) -> tuple[list[dict[str, Any]], list[str]]:
    """Fly ``tasks`` on the Dask scheduler at ``address``: their rows in the order of ``tasks``,
    and one line per landing that could not be flown (its row is a failed landing).
    ``finished(task, row, done)`` is called in this process as each landing comes back;
    ``timeout_s``: for the scheduler to answer and to have a worker (default CONNECT_TIMEOUT_S)."""
    client = _connect(address, CONNECT_TIMEOUT_S if timeout_s is None else timeout_s)
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    futures: dict[Any, LandingTask] = {}
    try:
        _check_workers(client)
        workers = len(client.scheduler_info(n_workers=-1)["workers"])
        log.info("flying %d landings on the Dask cluster at %s (%d workers)", len(tasks), address, workers)
        env = environment()
        shipped = {t.base: t.base.read_text() for t in tasks}
        campaign = uuid.uuid4().hex[:8]  # keys unique to this run: the scheduler shares results by key
        # the landings that render the camera are the long ones: handed out first (in this order
        # to the workers idle as they arrive, then by priority), the short ones fill the end
        for t in sorted(tasks, key=lambda t: (not renders_camera(t.variant), t.index)):
            landing = ClusterLanding(t, t.base.name, shipped[t.base], env)
            key = f"landing-{t.index}-seed-{t.draw.seed}-{t.variant}-{campaign}"
            payload = pickle.dumps(_FlownWhenLoaded(landing), protocol=pickle.HIGHEST_PROTOCOL)
            fut = client.submit(pickle.loads, payload, key=key, priority=int(renders_camera(t.variant)))
            futures[fut] = t
        rows: list[dict[str, Any] | None] = [None] * len(tasks)
        lost: list[str] = []
        t0 = time.perf_counter()
        for done, fut in enumerate(as_completed(list(futures), loop=client.loop), start=1):
            task = futures[fut]
            if fut.status == "error":
                err = fut.exception()
                if not isinstance(err, KilledWorker):
                    # the landing itself cannot raise here (fly_on_worker returns what it raises):
                    # the worker could not load it: this project is not installed there
                    raise ClusterError(
                        f"{task.name()} could not run on worker {_erred_on(client, fut.key)}: "
                        f"{_what(err)}; every worker needs `pip install -e '.[cluster]'` of this commit"
                    )
                attempts = err.allowed_failures + 1
                lost.append(
                    f"{task.name()} not flown: {attempts} workers died flying it "
                    f"(the last {err.last_worker.address}); counted as failed"
                )
                log.error("%s", lost[-1])
                row = unflown_row(task, f"not flown: {attempts} workers died flying it")
            else:
                kind, value = fut.result()
                if kind == "refused":
                    raise _refused(*value)
                if kind == "raised":
                    raise CampaignLandingError(f"{task.name()} {value}")
                row = value
            fut.release()
            rows[task.index] = row
            finished(task, row, done)
        log.info("%d landings flown on the cluster in %.1f s", len(tasks), time.perf_counter() - t0)
        return [r for r in rows if r is not None], lost
    except BaseException as err:
        if isinstance(err, KeyboardInterrupt):
            log.warning("interrupted; cancelling the campaign's landings on the cluster")
        client.cancel(list(futures))
        raise
    finally:
        client.close()
