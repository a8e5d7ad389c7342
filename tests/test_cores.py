"""scenelabel._cores: the jobs on a machine share its cores."""

from __future__ import annotations

import os
import subprocess
import sys

import psutil
import pytest
import torch

from scenelabel import _cores
from scenelabel._cores import share_summary, sharing_cores, update_share


@pytest.fixture
def threads():
    """Start every test at 4 torch threads (whatever the machine) and restore them after."""
    before = torch.get_num_threads()
    torch.set_num_threads(4)
    yield 4
    torch.set_num_threads(before)


@pytest.fixture(autouse=True)
def no_fixed_threads(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(_cores, "CHECK_SECONDS", 0.0)


def _register(registry, proc: psutil.Process) -> None:
    (registry / str(proc.pid)).write_text(repr(proc.create_time()))


@pytest.fixture
def other_job(tmp_path):
    """A running process registered as a job in tmp_path / "jobs"."""
    registry = tmp_path / "jobs"
    registry.mkdir()
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    _register(registry, psutil.Process(proc.pid))
    yield registry, proc
    proc.kill()
    proc.wait()


def test_alone_keeps_its_threads_and_leaves_no_entry(tmp_path, threads):
    registry = tmp_path / "jobs"
    with sharing_cores(registry):
        assert [p.name for p in registry.iterdir()] == [str(os.getpid())]
        assert torch.get_num_threads() == threads
        assert update_share() == threads
    assert list(registry.iterdir()) == []
    assert torch.get_num_threads() == threads


def test_two_jobs_take_half_each_and_the_survivor_takes_all_back(other_job, threads):
    registry, proc = other_job
    with sharing_cores(registry):
        assert torch.get_num_threads() == threads // 2  # the forced count at the start
        proc.kill()
        proc.wait()
        assert update_share() == threads
        assert [p.name for p in registry.iterdir()] == [str(os.getpid())]  # the ended job's entry is gone
    assert torch.get_num_threads() == threads


def test_summary_says_the_threads_and_the_other_jobs(other_job, threads):
    registry, _ = other_job
    assert share_summary() == "4 threads"
    with sharing_cores(registry):
        assert share_summary() == "2 threads, sharing the cores with 1 other scenelabel job"


def test_many_jobs_leave_at_least_one_thread(tmp_path, threads):
    registry = tmp_path / "jobs"
    registry.mkdir()
    procs = [subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]) for _ in range(5)]
    try:
        for p in procs:
            _register(registry, psutil.Process(p.pid))
        with sharing_cores(registry):
            assert torch.get_num_threads() == 1
            assert share_summary() == "1 thread, sharing the cores with 5 other scenelabel jobs"
    finally:
        for p in procs:
            p.kill()
            p.wait()
    assert torch.get_num_threads() == threads


def test_stale_and_foreign_entries_do_not_count(tmp_path, threads):
    registry = tmp_path / "jobs"
    registry.mkdir()
    ended = subprocess.Popen([sys.executable, "-c", "pass"])
    ended.wait()
    (registry / str(ended.pid)).write_text("0.0")  # a job that ended without removing its entry
    me = psutil.Process()
    (registry / str(me.ppid())).write_text(repr(me.create_time() + 1e4))  # a reused process id: wrong start time
    (registry / "not-a-pid").write_text("1.0")
    (registry / ".123.tmp-9").write_text("")  # an entry being written: skipped, kept
    with sharing_cores(registry):
        assert torch.get_num_threads() == threads
        assert sorted(p.name for p in registry.iterdir()) == sorted([".123.tmp-9", str(os.getpid())])


def test_a_job_started_by_another_process_counts(tmp_path, threads):
    """A real second process inside sharing_cores (the same registry) halves this one's threads."""
    registry = tmp_path / "jobs"
    code = (
        "import sys, time\nfrom pathlib import Path\nfrom scenelabel._cores import sharing_cores\n"
        f"with sharing_cores(Path({str(registry)!r})):\n    print('in', flush=True)\n    sys.stdin.readline()\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "in"
        with sharing_cores(registry):
            assert torch.get_num_threads() == threads // 2
            proc.communicate("\n", timeout=60)  # the other job leaves
            assert proc.returncode == 0
            assert update_share() == threads
    finally:
        proc.kill()


def test_omp_num_threads_keeps_the_threads_asked_for(other_job, threads, monkeypatch):
    registry, _ = other_job
    monkeypatch.setenv("OMP_NUM_THREADS", str(threads))
    with sharing_cores(registry):
        assert torch.get_num_threads() == threads
        assert (registry / str(os.getpid())).exists()  # it still counts for the others


def test_nested_use_is_one_job(tmp_path, threads):
    registry = tmp_path / "jobs"
    with sharing_cores(registry):
        with sharing_cores(registry / "elsewhere"):
            assert not (registry / "elsewhere").exists()
            assert update_share() == threads
        assert (registry / str(os.getpid())).exists()  # the inner end does not unregister the job
    assert not (registry / str(os.getpid())).exists()


def test_counted_at_most_every_check_seconds(other_job, threads, monkeypatch):
    registry, proc = other_job
    monkeypatch.setattr(_cores, "CHECK_SECONDS", 3600.0)
    with sharing_cores(registry):
        proc.kill()
        proc.wait()
        assert update_share() == threads // 2  # counted at the start, not again within the hour


def test_unwritable_registry_runs_alone(tmp_path, threads):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with sharing_cores(blocker / "jobs"):  # a folder under a file cannot be made
        assert torch.get_num_threads() == threads
    assert torch.get_num_threads() == threads


def test_a_registry_removed_meanwhile_counts_this_job_alone(other_job, threads):
    registry, _ = other_job
    with sharing_cores(registry):
        assert torch.get_num_threads() == threads // 2
        for entry in registry.iterdir():
            entry.unlink()
        registry.rmdir()  # a temp cleaner
        assert update_share() == threads
    assert torch.get_num_threads() == threads


def test_update_share_outside_is_a_no_op(threads):
    assert update_share() == threads


def test_default_registry_is_per_user_in_the_temp_dir():
    path = _cores.default_registry()
    assert path.name.startswith("scenelabel-jobs-")
    assert path.parent.is_dir()
