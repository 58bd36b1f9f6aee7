"""`companion campaign landing --cluster`: the landings flown on a Dask cluster (a local one of two
worker processes here) give the local pool's files bit for bit; a worker killed mid-landing has
its landing flown again elsewhere, and a landing that kills every worker it is given is named and
counted as failed; a scheduler that does not answer, a worker running another environment and a
landing that raises are each one clear line."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cloudpickle  # a dependency of distributed
import dask
import distributed  # in the [test] extra: these tests run wherever the others do
import pytest

from companion.cli import exits
from companion.cli.main import main
from companion_lab import campaign_cluster
from companion_lab.campaign_landing import CampaignLandingError
from companion_lab.landing_campaign import run_landing_campaign

# the plugin below is shipped to the workers by value (they cannot import this test module)
cloudpickle.register_pickle_by_value(sys.modules[__name__])

# the shipped campaign's scenario with the descent onto the pad from 8 m instead of 30 m: short
# landings (about 1 s each), the same code path
SHORT_PARAMS = """
vehicle_id = "drone1"
autopilot = "sim"

[mission]
height_m = 8.0
arc_radius_m = 4.0
sector_speed_m_s = [2.5, 3.0, 4.0, 2.0, 1.5]
takeoff_alt_m = 3.0
final_descent_alt_m = 3.0
land_speed_m_s = 0.5
return_home = false

[mission.pad]
lat_deg = -19.8688916
lon_deg = -43.9637141
alt_amsl_m = 850.0

[sim]
seed = 1

[sim.home]
lat_deg = -19.869
lon_deg = -43.9638
alt_amsl_m = 850.0
"""

# a worker given one landing at a time (one thread, no queue behind it), so a worker that dies
# takes only the landing it flies; a landing is tried on at most two workers
CLUSTER_CONFIG = {"distributed.scheduler.allowed-failures": 1, "distributed.scheduler.worker-saturation": 1.0}


def _local_cluster():
    with dask.config.set(CLUSTER_CONFIG):
        return distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=40
        )


class KillWorkerFlying(distributed.WorkerPlugin):
    """SIGKILLs the worker process ``after_s`` into flying a landing whose key starts with
    ``key_prefix`` (``landing-<index>-``), if it is still flying it: every time, or only the first
    time in the whole cluster when ``marker`` is a file path (created by the first attempt;
    ``<marker>.killed`` once the worker is killed). The landings aimed at are fusion ones (about
    2 s on a warm worker here; a GPS-only one takes 0.2 s)."""

    def __init__(self, key_prefix: str, marker: str | None = None, after_s: float = 0.3) -> None:
        self.key_prefix, self.marker, self.after_s = key_prefix, marker, after_s

    def setup(self, worker):
        self.worker = worker

    def transition(self, key, start, finish, *args, **kwargs):
        if finish != "executing" or not str(key).startswith(self.key_prefix):
            return
        if self.marker is not None:
            try:
                os.close(os.open(self.marker, os.O_CREAT | os.O_EXCL))
            except FileExistsError:
                return
        threading.Timer(self.after_s, self._kill, (key,)).start()

    def _kill(self, key):
        ts = self.worker.state.tasks.get(key)
        if ts is None or ts.state != "executing":
            return  # the landing ended first: no death mid-landing to test
        if self.marker is not None:
            Path(self.marker + ".killed").touch()
        os.kill(os.getpid(), signal.SIGKILL)


class _NoSuchPackage:
    """An import finder for which ``package`` is not installed."""

    def __init__(self, package: str) -> None:
        self.package = package

    def find_spec(self, name, path=None, target=None):
        if name == self.package or name.startswith(self.package + "."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


class WithoutPackage(distributed.WorkerPlugin):
    """The worker as on a machine where ``package`` is not installed."""

    def __init__(self, package: str) -> None:
        self.package = package

    def setup(self, worker):
        for name in [m for m in sys.modules if m == self.package or m.startswith(self.package + ".")]:
            del sys.modules[name]
        sys.meta_path.insert(0, _NoSuchPackage(self.package))


@pytest.fixture(scope="module")
def params(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("params") / "short_landing.toml"
    p.write_text(SHORT_PARAMS)
    return p


@pytest.fixture(scope="module")
def local_pool(tmp_path_factory, params) -> Path:
    """The campaign flown by the local pool (two worker processes): the reference files."""
    out = tmp_path_factory.mktemp("pool")
    argv = ["campaign", "landing", "--n", "2", "--seed", "5", "--params", str(params)]
    assert main([*argv, "--jobs", "2", "--out", str(out), "--quiet"]) == 0
    return out


@pytest.fixture(scope="module")
def cluster():
    with _local_cluster() as c:
        yield c


def _campaign(address: str, params: Path, out: Path) -> int:
    argv = ["campaign", "landing", "--n", "2", "--seed", "5", "--params", str(params), "--cluster", address]
    return main([*argv, "--out", str(out), "--quiet"])


def _same_files(a: Path, b: Path) -> None:
    for name in ("landing_campaign.json", "landing_scatter.png"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


@pytest.mark.flight
def test_the_cluster_flies_the_local_pools_campaign_bit_for_bit(cluster, params, local_pool, tmp_path, caplog):
    caplog.set_level("INFO", logger="companion_lab")
    assert _campaign(cluster.scheduler_address, params, tmp_path) == 0
    _same_files(tmp_path, local_pool)
    # progress as the local pool reports it: each landing as it comes back, counted
    done = [r.getMessage() for r in caplog.records if " done after " in r.getMessage()]
    assert len(done) == 4 and all(f"{k} of 4 done" in m for k, m in zip(range(1, 5), done, strict=True))


@pytest.mark.flight
def test_a_worker_killed_mid_landing_has_its_landing_flown_again(params, local_pool, tmp_path):
    with _local_cluster() as c, distributed.Client(c.scheduler_address) as client:
        client.register_plugin(KillWorkerFlying("landing-2-", marker=str(tmp_path / "killed")), name="kill")
        out = tmp_path / "out"
        assert _campaign(c.scheduler_address, params, out) == 0
    assert (tmp_path / "killed.killed").exists()  # the worker flying landing 3 was killed mid-landing, once
    _same_files(out, local_pool)


@pytest.mark.flight
def test_a_landing_that_kills_every_worker_is_named_and_counted_failed(params, local_pool, tmp_path, capsys):
    with _local_cluster() as c, distributed.Client(c.scheduler_address) as client:
        client.register_plugin(KillWorkerFlying("landing-0-"), name="kill")
        assert _campaign(c.scheduler_address, params, tmp_path) == exits.FAILED
    err = capsys.readouterr().err
    assert "landing 1 of 4 (seed 5000, fusion) not flown: 2 workers died flying it (the last tcp://" in err
    got = json.loads((tmp_path / "landing_campaign.json").read_text())
    ref = json.loads((local_pool / "landing_campaign.json").read_text())
    assert got["summary"]["fusion"]["failed"] == 1 and got["summary"]["fusion"]["n"] == 2
    assert got["landings"]["fusion"][0]["failure"] == "not flown: 2 workers died flying it"
    assert got["landings"]["fusion"][0]["seed"] == 5000
    # every other landing is the local pool's
    assert got["landings"]["gps_only"] == ref["landings"]["gps_only"]
    assert got["landings"]["fusion"][1] == ref["landings"]["fusion"][1]
    assert len(got["lost"]) == 1


def test_a_scheduler_that_does_not_answer_is_one_line_and_exit_7(tmp_path):
    # in a process of its own: the command's whole life is bounded, its exit included
    code = (
        "import sys; from companion_lab import campaign_cluster; campaign_cluster.CONNECT_TIMEOUT_S = 2.0; "
        "from companion.cli.main import main; "
        "sys.exit(main(['campaign', 'landing', '--n', '1', '--cluster', 'tcp://127.0.0.1:9', "
        f"'--out', {str(tmp_path)!r}]))"
    )
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    elapsed_s = time.monotonic() - t0
    assert done.returncode == exits.CLUSTER_UNAVAILABLE, done.stderr
    assert done.stderr.startswith(
        "companion campaign landing: no Dask scheduler answered at tcp://127.0.0.1:9 within 2 s"
    )
    assert "Traceback" not in done.stderr and done.stderr.count("\n") == 1, done.stderr
    # the command's imports (a few seconds on a loaded machine), the 2 s, and nothing after
    assert elapsed_s < 20.0


@pytest.mark.parametrize("address", ["localhost:port", "tcp://", "http://127.0.0.1:8786"])
def test_a_malformed_scheduler_address_is_bad_input(address, tmp_path, capsys):
    assert main(["campaign", "landing", "--n", "1", "--cluster", address, "--out", str(tmp_path)]) == exits.BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith(
        f"companion campaign landing: {address!r} is not a Dask scheduler's address (tcp://HOST:PORT)"
    )
    assert err.count("\n") == 1


def test_cluster_and_jobs_exclude_each_other(tmp_path, capsys):
    argv = ["campaign", "landing", "--n", "1", "--cluster", "tcp://127.0.0.1:9", "--jobs", "2", "--out", str(tmp_path)]
    assert main(argv) == exits.BAD_INPUT
    assert "--cluster and --jobs exclude each other" in capsys.readouterr().err


def test_a_worker_with_another_environment_is_refused_by_name(cluster, params, monkeypatch):
    real = campaign_cluster.environment()
    # this process's code as if it were another commit's: the workers' (real) hash differs
    monkeypatch.setattr(campaign_cluster, "environment", lambda: {**real, "code": "0" * 16})
    pattern = rf"worker tcp://127\.0\.0\.1:\d+ runs a different environment: code '{real['code']}' \(here '0{{16}}'\)"
    with pytest.raises(campaign_cluster.ClusterError, match=pattern):
        run_landing_campaign(1, 5, ("fusion",), params, cluster=cluster.scheduler_address)
    # a worker that joined after the check is refused by the landing it is given
    monkeypatch.setattr(campaign_cluster, "_check_workers", lambda client: None)
    with pytest.raises(campaign_cluster.ClusterError, match=pattern):
        run_landing_campaign(1, 5, ("fusion",), params, cluster=cluster.scheduler_address)


def test_a_landing_that_raises_on_a_worker_is_named(cluster, params):
    with pytest.raises(
        CampaignLandingError,
        match=r"landing [12] of 2 \(seed 5000, (fusion|gps_only)\) failed on worker tcp://\S+: ConfigError",
    ):
        run_landing_campaign(
            1,
            5,
            ("fusion", "gps_only"),
            params,
            tuning={"landing": {"no_such_key": 1.0}},
            cluster=cluster.scheduler_address,
        )


def test_a_worker_without_the_project_is_refused_by_name(params, monkeypatch):
    with _local_cluster() as c, distributed.Client(c.scheduler_address) as client:
        client.register_plugin(WithoutPackage("companion_lab"), name="without")
        pattern = r"worker tcp://127\.0\.0\.1:\d+ cannot run the campaign: ModuleNotFoundError"
        with pytest.raises(campaign_cluster.ClusterError, match=pattern + r".*No module named 'companion_lab'"):
            run_landing_campaign(1, 5, ("fusion",), params, cluster=c.scheduler_address)
        # a worker that joined after the check: the landing it cannot load names it
        monkeypatch.setattr(campaign_cluster, "_check_workers", lambda client: None)
        pattern = r"landing 1 of 1 \(seed 5000, fusion\) could not run on worker tcp://127\.0\.0\.1:\d+: "
        with pytest.raises(campaign_cluster.ClusterError, match=pattern + r".*No module named 'companion_lab'"):
            run_landing_campaign(1, 5, ("fusion",), params, cluster=c.scheduler_address)


@pytest.mark.flight
def test_ctrl_c_cancels_the_campaigns_landings_on_the_cluster(cluster, params):
    def interrupt(variant, done, total):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_landing_campaign(3, 5, ("fusion", "gps_only"), params, interrupt, cluster=cluster.scheduler_address)

    def tasks(dask_scheduler):
        return len(dask_scheduler.tasks)

    with distributed.Client(cluster.scheduler_address) as client:
        end = time.monotonic() + 10.0
        while client.run_on_scheduler(tasks) and time.monotonic() < end:
            time.sleep(0.1)
        assert client.run_on_scheduler(tasks) == 0  # nothing left flying or waiting
