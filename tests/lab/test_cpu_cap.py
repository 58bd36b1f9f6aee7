"""The CPU cap's cgroup module on a fake cgroup tree (a tmp dir): finding the controller, the quota,
the files written, and the errors that name the file."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from companion_lab import cpu_cap
from companion_lab.cpu_cap import CpuCapError, CpuCgroup, CpuController, find_cpu_controller, parse_cap, quota_us

# /proc/self/mountinfo of a cgroup v1 machine (this project's development machine) and of a cgroup
# v2 one (systemd's unified hierarchy)
MOUNTINFO_V1 = """\
24 30 0:22 / /sys/fs/cgroup rw,nosuid,nodev,noexec,relatime shared:9 - tmpfs tmpfs rw,mode=755
31 24 0:27 / /sys/fs/cgroup/unified rw,relatime - cgroup2 cgroup2 rw
32 24 0:28 / /sys/fs/cgroup/cpu rw,relatime - cgroup cgroup rw,cpu
33 24 0:29 / /sys/fs/cgroup/cpuacct rw,relatime - cgroup cgroup rw,cpuacct
34 24 0:30 / /sys/fs/cgroup/memory rw,relatime - cgroup cgroup rw,memory
"""
CGROUP_V1 = "9:name=systemd:/\n4:memory:/job/7\n2:cpuacct:/\n1:cpu:/jobs/a\n0::/\n"
MOUNTINFO_V2 = "35 24 0:31 / /sys/fs/cgroup rw,nosuid,nodev,noexec,relatime shared:10 - cgroup2 cgroup2 rw\n"
CGROUP_V2 = "0::/user.slice/session-1.scope\n"


def _v1_tree(root: Path, rel: str = "jobs/a") -> Path:
    d = root / "sys/fs/cgroup/cpu" / rel
    d.mkdir(parents=True)
    (root / "sys/fs/cgroup/unified").mkdir(parents=True)
    (root / "sys/fs/cgroup/unified/cgroup.controllers").write_text("hugetlb\n")  # no cpu in v2 here
    return d


def test_parse_cap_forms():
    assert parse_cap("0.25") == 0.25
    assert parse_cap("25%") == 0.25
    assert parse_cap("pi4") == cpu_cap.PI4_FACTOR
    assert parse_cap("PI4", pi4_factor=0.2) == 0.2
    assert parse_cap("2") == 2.0  # two whole cores


@pytest.mark.parametrize("bad", ["abc", "", "0", "-0.1", "nan", "inf", "65", "pi5"])
def test_parse_cap_refuses_with_what_is_expected(bad):
    with pytest.raises(CpuCapError, match=r"--cpu-cap"):
        parse_cap(bad)


def test_the_pi4_factor_is_the_ratio_of_the_two_n_body_times():
    assert round(cpu_cap.EPYC_NBODY_5M_S / cpu_cap.PI4_NBODY_5M_S, 3) == cpu_cap.PI4_FACTOR
    assert 0.0 < cpu_cap.PI4_FACTOR < 1.0
    assert "158.263" in cpu_cap.PI4_NBODY_SOURCE


def test_the_period_is_short_but_keeps_the_quota_over_the_kernels_floor():
    assert cpu_cap.period_for(0.13) == cpu_cap.PERIOD_US == 10_000
    assert cpu_cap.period_for(0.05) == 20_000  # 1 ms of quota
    assert quota_us(0.05, cpu_cap.period_for(0.05)) == cpu_cap.MIN_QUOTA_US


def test_quota_us():
    assert quota_us(0.25) == 2_500
    assert quota_us(0.25, 100_000) == 25_000
    assert quota_us(0.13, 100_000) == 13_000
    assert quota_us(1.5, 10_000) == 15_000  # more than one core: quota over the period
    assert quota_us(0.0001) == cpu_cap.MIN_QUOTA_US  # the kernel's floor
    with pytest.raises(CpuCapError, match="period"):
        quota_us(0.5, 500)
    with pytest.raises(CpuCapError, match="positive"):
        quota_us(-1.0)


def test_nbody_is_the_benchmarks_game_program():
    e0, e1, cpu_s = cpu_cap.nbody(1000)
    assert (round(e0, 9), round(e1, 9)) == cpu_cap.NBODY_ENERGY_1000
    assert cpu_s >= 0.0


def test_finds_v1_when_v2_has_no_cpu_controller(tmp_path):
    d = _v1_tree(tmp_path)
    ctl = find_cpu_controller(MOUNTINFO_V1, CGROUP_V1, prefix=tmp_path)
    assert ctl == CpuController(1, d)


def test_prefers_v2_when_it_has_the_cpu_controller(tmp_path):
    (tmp_path / "sys/fs/cgroup").mkdir(parents=True)
    (tmp_path / "sys/fs/cgroup/cgroup.controllers").write_text("cpuset cpu io memory pids\n")
    ctl = find_cpu_controller(MOUNTINFO_V2, CGROUP_V2, prefix=tmp_path)
    assert ctl == CpuController(2, tmp_path / "sys/fs/cgroup/user.slice/session-1.scope")


def test_no_controller_is_an_error_saying_what_was_looked_for(tmp_path):
    mi = "24 30 0:22 / /sys/fs/cgroup rw - tmpfs tmpfs rw\n"
    with pytest.raises(CpuCapError, match=r"mountinfo.*cpu"):
        find_cpu_controller(mi, CGROUP_V2, prefix=tmp_path)


def test_v1_cgroup_writes_period_and_quota_and_moves_tasks(tmp_path):
    d = _v1_tree(tmp_path)
    cg = CpuCgroup(CpuController(1, d), 0.13, "cap-test")
    assert (d / "cap-test/cpu.cfs_period_us").read_text() == "10000\n"
    assert (d / "cap-test/cpu.cfs_quota_us").read_text() == "1300\n"
    cg.add_pid(1234)
    assert (d / "cap-test/cgroup.procs").read_text() == "1234\n"
    cg.add_tid(1235)
    assert (d / "cap-test/tasks").read_text() == "1235\n"
    cg.release_tid(1235)
    assert (d / "tasks").read_text() == "1235\n"
    assert "cpu.cfs_quota_us 1300 us per 10000 us" in cg.describe()


def test_v2_cgroup_enables_the_controller_and_writes_cpu_max(tmp_path):
    d = tmp_path / "grp"
    d.mkdir()
    cg = CpuCgroup(CpuController(2, d), 0.5, "cap-test", period_us=50_000)
    assert (d / "cgroup.subtree_control").read_text() == "+cpu"
    assert (d / "cap-test/cpu.max").read_text() == "25000 50000\n"
    with pytest.raises(CpuCapError, match="only on cgroup v1"):
        cg.add_tid(1)


def test_throttle_stats_are_read_from_cpu_stat(tmp_path):
    d = _v1_tree(tmp_path)
    cg = CpuCgroup(CpuController(1, d), 0.2, "cap-test")
    (d / "cap-test/cpu.stat").write_text("nr_periods 50\nnr_throttled 7\nthrottled_time 123456789\n")
    assert cg.throttled() == {"nr_periods": 50, "nr_throttled": 7, "throttled_time": 123456789}


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes read-only files")
def test_a_file_that_is_not_writable_is_named(tmp_path):
    d = _v1_tree(tmp_path)
    child = d / "cap-test"
    child.mkdir()
    (child / "cpu.cfs_period_us").write_text("10000\n")
    (child / "cpu.cfs_period_us").chmod(0o444)
    with pytest.raises(CpuCapError, match=r"cpu\.cfs_period_us: cannot write '10000'"):
        CpuCgroup(CpuController(1, d), 0.13, "cap-test")


def test_a_missing_cgroup_directory_is_named(tmp_path):
    # the controller's directory is a file: neither root nor anyone can make a cgroup under it
    f = tmp_path / "not-a-dir"
    f.write_text("")
    with pytest.raises(CpuCapError, match=r"not-a-dir/cap-test: cannot create the cgroup"):
        CpuCgroup(CpuController(1, f), 0.13, "cap-test")


def test_an_unwritable_quota_file_is_named_even_for_root(tmp_path):
    # a directory where the quota file should be: the write fails for root too
    d = _v1_tree(tmp_path)
    (d / "cap-test/cpu.cfs_quota_us").mkdir(parents=True)
    with pytest.raises(CpuCapError, match=r"cap-test/cpu\.cfs_quota_us: cannot write '1300'"):
        CpuCgroup(CpuController(1, d), 0.13, "cap-test")


def test_remove_moves_what_is_left_back_to_the_parent(tmp_path):
    d = _v1_tree(tmp_path)
    cg = CpuCgroup(CpuController(1, d), 0.2, "cap-test")
    (d / "cap-test/tasks").write_text("11\n12\n")
    assert cg.remove(attempts=2) is False  # the fake directory keeps its files (a real cgroup's go with it)
    assert (d / "tasks").read_text() == "12\n"  # each written in turn (the kernel moves each one)
    for f in (d / "cap-test").iterdir():
        f.unlink()
    assert cg.remove() is True and not (d / "cap-test").exists()


def test_caps_left_behind_are_swept_and_one_in_use_is_kept(tmp_path):
    d = _v1_tree(tmp_path)
    (d / "companion-cpucap-1").mkdir()  # empty: an earlier run's
    busy = d / "companion-cpucap-2"
    busy.mkdir()
    (busy / "tasks").write_text("77\n")  # in use (a real cgroup refuses rmdir; the fake, not empty)
    (d / "someone-else").mkdir()
    gone = cpu_cap.sweep_stale(CpuController(1, d))
    assert gone == [d / "companion-cpucap-1"]
    assert busy.exists() and (d / "someone-else").exists()


def test_cli_refuses_a_bad_cap():
    assert cpu_cap.main(["run", "--cap", "abc", "--", "true"]) == 2


class _RecordingCgroup(CpuCgroup):
    """A v1 cgroup on the fake tree that records the threads it moves back out."""

    def __init__(self, controller: CpuController) -> None:
        super().__init__(controller, 0.13, "cap-keeper")
        self.released: list[int] = []

    def release_tid(self, tid: int) -> None:
        self.released.append(tid)


def test_the_keeper_moves_the_worlds_threads_out_and_leaves_the_companions(tmp_path):
    import threading

    cg = _RecordingCgroup(CpuController(1, _v1_tree(tmp_path)))
    stop = threading.Event()
    threads = [
        threading.Thread(target=stop.wait, name=n, daemon=True)
        for n in ("truth-feed", "sim-camera-render_0", "landing-vision", "ThreadPoolExecutor-0_0")
    ]
    for t in threads:
        t.start()
    try:
        keeper = cpu_cap.CapKeeper(cg)
        keeper.sweep()
        keeper.sweep()  # a thread already out is not moved again
        assert sorted(cg.released) == sorted(t.native_id for t in threads[:2])
        assert not keeper.world_inside
    finally:
        stop.set()


def test_the_keeper_on_cgroup_v2_says_the_world_stays_inside(tmp_path):
    d = tmp_path / "sys/fs/cgroup/user.slice"
    d.mkdir(parents=True)
    cg = _RecordingCgroup(CpuController(2, d))
    keeper = cpu_cap.CapKeeper(cg)
    keeper.sweep()
    assert keeper.world_inside and cg.released == []


def test_the_keepers_own_thread_is_a_world_thread(tmp_path):
    cg = _RecordingCgroup(CpuController(1, _v1_tree(tmp_path)))
    keeper = cpu_cap.CapKeeper(cg, period_s=0.01)
    keeper.start()
    try:
        tid = keeper.native_thread_id
        assert tid is not None
        for _ in range(200):
            if tid in cg.released:
                break
            time.sleep(0.01)
        assert tid in cg.released
    finally:
        keeper.stop()
    assert keeper.native_thread_id is None


def test_the_factor_measured_here_is_calibrates_ratio_and_is_measured_once(monkeypatch):
    calls: list[int] = []

    def fake_calibrate(steps: int) -> cpu_cap.Calibration:
        calls.append(steps)
        return cpu_cap.Calibration(31.65, cpu_cap.PI4_NBODY_5M_S, 31.65 / cpu_cap.PI4_NBODY_5M_S)

    monkeypatch.setattr(cpu_cap, "calibrate", fake_calibrate)
    cpu_cap.pi4_factor_here.cache_clear()
    try:
        assert cpu_cap.pi4_factor_here() == pytest.approx(0.2, abs=1e-3)
        assert cpu_cap.pi4_factor_here() == pytest.approx(0.2, abs=1e-3)
        assert calls == [500_000]  # a tenth of calibrate's run, once per process
    finally:
        cpu_cap.pi4_factor_here.cache_clear()
