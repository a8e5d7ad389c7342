"""Sharing a machine's cores between the scenelabel jobs running on it at once.

torch runs its CPU ops on OpenMP threads, which spin while they wait for the next parallel region.
Two builds with two threads each on a two-core machine take turns with each other's spinning
threads: docs/threads.md measured each build 5x slower than alone, and 3x slower than with one
thread each. So a job (a build, a chunked map export) registers while it runs: a file named by its
process id in a per-user folder of the temp directory. Between training steps, at most once every
CHECK_SECONDS, it counts the jobs registered and alive and sets torch's threads to its share:
the threads it started with divided by the jobs, at least one. When the others end, it takes its
threads back. A process started with ``OMP_NUM_THREADS`` set keeps the threads that asked for
(it still registers, so the others make room for it).

A build's float results can depend on its thread count, so a build reproduces another of the same
seed exactly when both ran alone or both with ``OMP_NUM_THREADS`` set.
"""

from __future__ import annotations

import contextlib
import getpass
import os
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import psutil
import torch

from scenelabel._files import atomic_write_bytes

__all__ = ["CHECK_SECONDS", "default_registry", "share_summary", "sharing_cores", "update_share"]

CHECK_SECONDS = 1.0
"""Jobs are counted at most this often (a count lists a folder and looks up a few processes)."""


def default_registry() -> Path:
    """The folder where this user's running jobs register: ``<temp>/scenelabel-jobs-<user>``."""
    try:
        user = getpass.getuser()
    except (KeyError, OSError):  # no user name (some containers)
        user = str(os.getuid()) if hasattr(os, "getuid") else "user"
    return Path(tempfile.gettempdir()) / f"scenelabel-jobs-{user}"


def _alive(entry: Path) -> bool:
    """Whether ``entry`` (named by a process id, holding its start time) names a running process;
    a process id that was reused by a later process does not count."""
    try:
        pid, created = int(entry.name), float(entry.read_text())
        return abs(psutil.Process(pid).create_time() - created) < 1e-2
    except (ValueError, OSError, psutil.Error):
        return False


class _Share:
    """This process's registration and the threads it started with."""

    def __init__(self, registry: Path):
        self.threads = torch.get_num_threads()
        self.fixed = bool(os.environ.get("OMP_NUM_THREADS"))
        self.checked = -float("inf")
        self.others = 0
        self.entry: Path | None = registry / str(os.getpid())
        try:
            registry.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(self.entry, repr(psutil.Process().create_time()).encode())
        except OSError:  # no writable temp directory: this job counts only itself
            self.entry = None

    def jobs(self) -> int:
        """The jobs registered and running, this one included; entries of ended processes are removed.
        A registry that cannot be read (removed by a temp cleaner) counts this job alone."""
        if self.entry is None:
            return 1
        try:  # "." : an entry being written (atomic_write_bytes's temp file)
            others = [e for e in self.entry.parent.iterdir() if e != self.entry and not e.name.startswith(".")]
        except OSError:
            return 1
        count = 1
        for entry in others:
            if _alive(entry):
                count += 1
            else:
                with contextlib.suppress(OSError):
                    entry.unlink()
        return count

    def update(self, force: bool = False) -> int:
        now = time.monotonic()
        if not self.fixed and (force or now - self.checked >= CHECK_SECONDS):
            self.checked = now
            jobs = self.jobs()
            self.others = jobs - 1
            share = max(1, self.threads // jobs)
            if share != torch.get_num_threads():
                torch.set_num_threads(share)
        return torch.get_num_threads()

    def close(self) -> None:
        if self.entry is not None:
            with contextlib.suppress(OSError):
                self.entry.unlink()
        torch.set_num_threads(self.threads)


_SHARE: _Share | None = None


@contextlib.contextmanager
def sharing_cores(registry: Path | None = None) -> Iterator[None]:
    """While inside (``with sharing_cores():`` or ``@sharing_cores()``), this process is one of the
    jobs that share the machine's cores, and :func:`update_share` sets its torch threads to its
    share; at the end its threads are what they were. Nested uses are one job.

    Args:
        registry: the folder the jobs register in (default: :func:`default_registry`).
    """
    global _SHARE
    if _SHARE is not None:
        yield
        return
    _SHARE = _Share(registry or default_registry())
    try:
        _SHARE.update(force=True)
        yield
    finally:
        _SHARE.close()
        _SHARE = None


def share_summary() -> str:
    """torch's threads now, and the other jobs this process shares the cores with when it does."""
    threads = torch.get_num_threads()
    text = f"{threads} thread{'s' * (threads != 1)}"
    others = _SHARE.others if _SHARE is not None else 0
    if others:
        text += f", sharing the cores with {others} other scenelabel job{'s' * (others != 1)}"
    return text


def update_share() -> int:
    """Set torch's threads to this job's share: the threads it started with divided by the running
    jobs, at least one (unless ``OMP_NUM_THREADS`` fixed them, or the jobs were counted less than
    CHECK_SECONDS ago, or no :func:`sharing_cores` is active); returns the threads now in use.
    Cheap enough to call between training steps."""
    return _SHARE.update() if _SHARE is not None else torch.get_num_threads()
