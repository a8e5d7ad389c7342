"""Many scenes: ``build`` over a list of scene folders as independent jobs, one field each.

Each scene is one job, :func:`build_scene`: a function of the scene path, its output folder and
the config as a plain dict (:func:`scenelabel.config.config_to_dict`) alone, so it runs the same
in this process or as a task on a Dask cluster (``client.submit``). A job never raises for a bad
scene: it writes the traceback into the scene's ``build.log`` and returns a failed
:class:`SceneOutcome`, and the other scenes go on. :func:`build_many` runs the jobs, one after
another here or on a ``dask.distributed.Client``, and writes ``summary.md`` and ``summary.json``
into the output root.

A job's ``build.log`` holds its own lines (start, config, end or failure with traceback), the
training progress (one line every :data:`PROGRESS_LOG_EVERY` seconds and the last), every Python
warning and every ``logging`` record (INFO and up for scenelabel's loggers) of that job. Capture is
per thread, so jobs that share a process do not mix their logs; Python's warnings machinery is
process-wide, though, so give a Dask worker one thread (``threads_per_worker=1``) for clean logs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import os
import re
import socket
import sys
import threading
import time
import traceback
import uuid
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from scenelabel._files import atomic_write_bytes
from scenelabel._version import __version__
from scenelabel.config import BuildConfig, config_from_dict, config_to_dict, preset
from scenelabel.data.video import is_video, video_scene_dir
from scenelabel.errors import InputError, TrainingInterrupted
from scenelabel.train.pipeline import build

__all__ = [
    "build_many",
    "build_scene",
    "SceneOutcome",
    "out_dirs_for",
    "summary_table",
    "write_summary",
    "LOG_NAME",
    "SUMMARY_MD",
    "SUMMARY_JSON",
]

LOG_NAME = "build.log"
SUMMARY_MD = "summary.md"
SUMMARY_JSON = "summary.json"
PROGRESS_LOG_EVERY = 10.0
"""Seconds between training-progress lines in a job's build.log (the last state is always written)."""

SUMMARY_METRICS = (
    "steps",
    "train_seconds",
    "steps_per_second",
    "n_test_views",
    "psnr",
    "ssim",
    "miou",
    "miou_common",
    "miou_smoothed",
    "depth_error",
)
"""The keys of a build's metrics.json that a :class:`SceneOutcome` keeps."""


@dataclass
class SceneOutcome:
    """What one scene's job came to.

    ``scene`` is the folder as given; ``out_dir`` its output folder; ``log`` its ``build.log``
    (None when the output folder could not be made). On success ``metrics`` holds
    :data:`SUMMARY_METRICS` (those present); on failure ``error`` is the error's message and
    ``error_type`` its class name (``InputError``, ``TrainingError``, ...). ``warnings`` are the
    job's Python warnings, one line each; ``seconds`` the job's wall time.
    """

    scene: str
    out_dir: Path
    ok: bool
    seconds: float
    log: Path | None
    metrics: dict = field(default_factory=dict)
    error: str | None = None
    error_type: str | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def status(self) -> str:
        return "ok" if self.ok else "failed"

    def to_dict(self) -> dict:
        """A JSON-ready dict (paths as strings)."""
        data = dataclasses.asdict(self)
        data["status"] = self.status
        data["out_dir"] = str(self.out_dir)
        data["log"] = None if self.log is None else str(self.log)
        return data

    def one_line(self) -> str:
        """``scene: ok in 12.3 s (psnr 21.04, miou 0.812)`` or ``scene: failed: InputError: ...``."""
        if not self.ok:
            return f"{self.scene}: failed after {self.seconds:.1f} s: {self.error_type}: {_first_line(self.error)}"
        shown = ", ".join(f"{k} {self.metrics[k]:.4g}" for k in ("psnr", "miou") if k in self.metrics)
        return f"{self.scene}: ok in {self.seconds:.1f} s" + (f" ({shown})" if shown else "")


# ----------------------------------------------------------------------------------------------
# Per-job capture of stderr (the progress bar), warnings and logging records, routed by thread


def _first_line(text: str | None) -> str:
    lines = (text or "").strip().splitlines()
    return lines[0] if lines else ""


class _JobLog:
    """One job's build.log (or nowhere, when ``file`` is None): timestamped lines, warnings kept."""

    def __init__(self, file):
        self.file = file
        self.warnings: list[str] = []
        self.progress = _ProgressLines(self.line, PROGRESS_LOG_EVERY)

    def line(self, text: str) -> None:
        if self.file is not None:
            self.file.write(f"{time.strftime('%H:%M:%S')} {text}\n")

    def raw(self, text: str) -> None:
        if self.file is not None:
            self.file.write(text if text.endswith("\n") else text + "\n")

    def warning(self, text: str) -> None:
        self.warnings.append(text)
        self.line(f"warning: {text}")

    def close(self) -> None:
        self.progress.close()
        if self.file is not None:
            self.file.close()


class _ProgressLines:
    """A write-only text stream that turns a tqdm bar (``\\r`` redraws) into log lines.

    A line ended by ``\\n`` is written at once; a redrawn bar state at most every ``every``
    seconds, and its last state when the bar ends (or on close).
    """

    encoding = "utf-8"

    def __init__(self, emit, every: float):
        self._emit = emit
        self._every = every
        self._buffer = ""
        self._pending: str | None = None
        self._last = -math.inf

    def write(self, text: str) -> int:
        for part in re.split(r"([\r\n])", text):
            if part == "\r":
                self._bar(self._buffer)
                self._buffer = ""
            elif part == "\n":
                self._pending = None  # a finished line supersedes the bar state before it
                if self._buffer.strip():
                    self._emit(self._buffer.rstrip())
                self._buffer = ""
            else:
                self._buffer += part
        return len(text)

    def _bar(self, text: str) -> None:
        text = text.rstrip()
        if not text:
            return
        now = time.monotonic()
        if now - self._last >= self._every:
            self._emit(text)
            self._last, self._pending = now, None
        else:
            self._pending = text

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False

    def close(self) -> None:
        if self._buffer.strip():
            self._pending = self._buffer.rstrip()
        self._buffer = ""
        if self._pending:
            self._emit(self._pending)
            self._pending = None


class _StderrRouter:
    """Stands in for ``sys.stderr`` while jobs run: a registered job thread's writes go to its
    log's progress stream, every other thread's to the stream it replaced."""

    def __init__(self, fallback):
        self.fallback = fallback

    def _target(self):
        log = _routes.get(threading.get_ident())
        return self.fallback if log is None else log.progress

    def write(self, text: str) -> int:
        return self._target().write(text)

    def flush(self) -> None:
        self._target().flush()

    def isatty(self) -> bool:
        return self._target().isatty()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._target(), name)


def _route_warning(message, category, filename, lineno, file=None, line=None) -> None:
    log = _routes.get(threading.get_ident())
    if log is not None:
        log.warning(f"{category.__name__}: {message}")
        return
    fallback = _saved.get("showwarning")
    if fallback is not None and fallback is not _route_warning:
        fallback(message, category, filename, lineno, file, line)
    else:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


class _ThreadHandler(logging.Handler):
    """Writes the logging records of one thread into that thread's job log."""

    def __init__(self, log: _JobLog, thread: int):
        super().__init__(logging.INFO)
        self.log, self.thread = log, thread
        self.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self.thread:
            self.log.line(self.format(record))


_capture_lock = threading.Lock()
_routes: dict[int, _JobLog] = {}
_saved: dict[str, Any] = {}  # what the first capturing job replaced; the last one puts it back


@contextlib.contextmanager
def _capture(log: _JobLog):
    """Route this thread's stderr, warnings and logging records into ``log`` for the block."""
    thread = threading.get_ident()
    package_logger = logging.getLogger("scenelabel")
    with _capture_lock:
        if not _routes:
            _saved["stderr"] = sys.stderr
            sys.stderr = _StderrRouter(sys.stderr)
            _saved["showwarning"] = warnings.showwarning
            warnings.showwarning = _route_warning
            _saved["level"] = package_logger.level
            if package_logger.getEffectiveLevel() > logging.INFO:
                package_logger.setLevel(logging.INFO)  # sfm's progress lines are INFO records
        _routes[thread] = log
        # entering catch_warnings invalidates the modules' "already shown" registries, so a
        # warning this job repeats from an earlier job in this process is shown (logged) again
        with warnings.catch_warnings():
            pass
    handler = _ThreadHandler(log, thread)
    logging.getLogger().addHandler(handler)
    try:
        yield
    finally:
        logging.getLogger().removeHandler(handler)
        with _capture_lock:
            _routes.pop(thread, None)
            if not _routes:
                if isinstance(sys.stderr, _StderrRouter):
                    sys.stderr = _saved["stderr"]
                if warnings.showwarning is _route_warning:
                    warnings.showwarning = _saved["showwarning"]
                package_logger.setLevel(_saved["level"])
                _saved.clear()
            with warnings.catch_warnings():  # nor is a warning the job logged suppressed after it
                pass


# ----------------------------------------------------------------------------------------------
# One job


def build_scene(scene: str | Path, out_dir: str | Path, config: dict, device: str | None = None) -> SceneOutcome:
    """Build one scene into ``out_dir``, logging into ``out_dir/build.log``; never raises for a bad scene.

    The job of :func:`build_many`: a function of its arguments alone (``config`` is a dict from
    :func:`scenelabel.config.config_to_dict`), so it can be submitted to a Dask cluster as is.
    Any exception (a bad scene folder, a bad config, a diverged training run, ...) is written to
    the log with its traceback and returned as a failed :class:`SceneOutcome`. Only an
    interruption (Ctrl-C, :class:`~scenelabel.errors.TrainingInterrupted`) is raised, after it is
    logged. ``out_dir`` is made when its parent exists (so a missing scene folder is not created
    to hold ``<scene>/scenelabel``); otherwise the job logs nowhere (``log`` None).
    """
    scene, out_dir = Path(scene), Path(out_dir)
    start = time.perf_counter()
    log_path: Path | None = out_dir / LOG_NAME
    try:
        out_dir.mkdir(exist_ok=True)
        file = open(log_path, "w", encoding="utf-8", buffering=1)
    except OSError:
        log_path, file = None, None
    log = _JobLog(file)
    log.line(f"scenelabel {__version__}: build {scene} -> {out_dir} (host {socket.gethostname()}, pid {os.getpid()})")
    try:
        try:
            with _capture(log):
                cfg = config_from_dict(config)
                log.line(f"preset {cfg.preset}, steps {cfg.train.steps}, seed {cfg.train.seed}, device {device or 'auto'}")
                result = build(scene, out_dir, cfg, progress=True, device=device)
        except (KeyboardInterrupt, TrainingInterrupted) as err:
            log.line(f"interrupted after {time.perf_counter() - start:.1f} s: {err or type(err).__name__}")
            raise
        except Exception as err:
            seconds = time.perf_counter() - start
            log.line(f"failed after {seconds:.1f} s: {type(err).__name__}: {_first_line(str(err))}")
            log.raw(traceback.format_exc())
            return SceneOutcome(
                str(scene), out_dir, False, seconds, log_path, error=str(err), error_type=type(err).__name__,
                warnings=log.warnings,
            )
        seconds = time.perf_counter() - start
        metrics = {k: result.metrics[k] for k in SUMMARY_METRICS if k in result.metrics}
        shown = ", ".join(f"{k}={metrics[k]:.4f}" for k in ("psnr", "ssim", "miou", "depth_error") if k in metrics)
        log.line(f"finished in {seconds:.1f} s: {metrics.get('steps')} steps" + (f", {shown}" if shown else ""))
        return SceneOutcome(str(scene), out_dir, True, seconds, log_path, metrics=metrics, warnings=log.warnings)
    finally:
        log.close()


# ----------------------------------------------------------------------------------------------
# Many jobs


def out_dirs_for(scenes: Iterable[str | Path], out_root: str | Path | None = None) -> list[Path]:
    """Each scene's output folder: ``<out_root>/<scene folder name>``, or ``<scene>/scenelabel``
    when ``out_root`` is None (a video ``clip.mp4``: its scene folder ``clip/``); a name already taken
    gets ``_2``, ``_3``, ... appended."""
    root = None if out_root is None else Path(out_root).absolute()
    taken = set() if root is None else {root / SUMMARY_MD, root / SUMMARY_JSON}
    dirs = []
    for scene in scenes:
        scene = Path(scene).absolute()
        if is_video(scene):  # a video's scene folder: clip/ beside clip.mp4
            scene = video_scene_dir(scene)
        base = scene / "scenelabel" if root is None else root / (scene.resolve().name or "scene")
        candidate, n = base, 1
        while candidate in taken:
            n += 1
            candidate = base.with_name(f"{base.name}_{n}")
        taken.add(candidate)
        dirs.append(candidate)
    return dirs


def _config_dict(config: BuildConfig | dict | None) -> dict:
    if config is None:
        config = preset()
    elif isinstance(config, dict):
        config = config_from_dict(config)  # a bad config fails the batch up front, not each scene
    return config_to_dict(config)


def _say(text: str) -> None:
    print(f"scenelabel: {text}", file=sys.stderr, flush=True)


def _lost_job(scene: str, out_dir: Path, err: BaseException, seconds: float) -> SceneOutcome:
    """A failed outcome for a job whose task itself failed (a worker died, the task was cancelled)."""
    message = str(err) or type(err).__name__
    log: Path | None = out_dir / LOG_NAME
    try:
        with open(log, "a", encoding="utf-8") as f:
            f.write(f"{time.strftime('%H:%M:%S')} the job was lost: {type(err).__name__}: {_first_line(message)}\n")
    except OSError:
        log = log if log.is_file() else None
    return SceneOutcome(scene, out_dir, False, seconds, log, error=message, error_type=type(err).__name__)


def build_many(
    scenes: Iterable[str | Path],
    out_root: str | Path | None = None,
    config: BuildConfig | dict | None = None,
    *,
    client=None,
    device: str | None = None,
    progress: bool = False,
) -> list[SceneOutcome]:
    """Build every scene folder as an independent job (one field each); a failed scene does not stop the others.

    Args:
        scenes: scene folders (see docs/formats.md).
        out_root: each scene is written to ``<out_root>/<scene folder name>`` (``_2``, ... for a
            repeated name), with ``summary.md`` and ``summary.json`` beside them. None: each scene
            to its default ``<scene>/scenelabel`` and no summary files.
        config: the config of every build (a BuildConfig or its dict; default: the ``fast`` preset).
        client: a ``dask.distributed.Client``: each scene is one task (:func:`build_scene`),
            gathered as they complete. None: the jobs run one after another in this process.
        device: 'cpu', 'cuda' or None (CUDA when available), where each job runs.
        progress: print a line to stderr as each scene starts (here) or is sent, and as each ends.
    Returns:
        One :class:`SceneOutcome` per scene, in the order given; each scene's ``build.log`` holds
        its progress, warnings and, on failure, the traceback.
    Raises:
        InputError: no scenes, or ``out_root`` cannot be made. ConfigError: a bad ``config``.
    """
    labels = [str(s) for s in scenes]
    if not labels:
        raise InputError("no scene folders given")
    config_dict = _config_dict(config)
    if out_root is not None:
        out_root = Path(out_root)
        try:
            out_root.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise InputError(f"cannot create the output folder: {err.strerror or err}", path=out_root) from None
    out_dirs = out_dirs_for(labels, out_root)
    jobs = [(label, str(Path(label).absolute()), str(out)) for label, out in zip(labels, out_dirs)]
    n = len(jobs)
    outcomes: list[SceneOutcome | None] = [None] * n
    if client is None:
        for i, (label, scene, out) in enumerate(jobs):
            if progress:
                _say(f"[{i + 1}/{n}] building {label} -> {out}")
            outcomes[i] = dataclasses.replace(build_scene(scene, out, config_dict, device), scene=label)
            if progress:
                _say(f"[{i + 1}/{n}] {outcomes[i].one_line()}")
    else:
        from distributed import as_completed

        batch = uuid.uuid4().hex[:8]
        submitted = time.perf_counter()
        futures = {
            client.submit(build_scene, scene, out, config_dict, device, key=f"scenelabel-build-{batch}-{i}-{Path(out).name}"): i
            for i, (label, scene, out) in enumerate(jobs)
        }
        if progress:
            _say(f"sent {n} scenes to the Dask cluster at {getattr(client.scheduler, 'address', '?')}")
        done = 0
        try:
            for future in as_completed(futures):
                i = futures[future]
                label, _, out = jobs[i]
                try:
                    outcomes[i] = dataclasses.replace(future.result(), scene=label)
                except Exception as err:  # the task itself failed: a worker died, it was cancelled, ...
                    outcomes[i] = _lost_job(label, Path(out), err, time.perf_counter() - submitted)
                future.release()
                done += 1
                if progress:
                    _say(f"[{done}/{n}] {outcomes[i].one_line()}")
        finally:
            pending = [f for f in futures if not f.done()]
            if pending:
                client.cancel(pending)
    if out_root is not None:
        write_summary(outcomes, out_root)
    return outcomes


# ----------------------------------------------------------------------------------------------
# The summary


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _number(metrics: dict, key: str, fmt: str) -> str:
    value = metrics.get(key)
    return "-" if value is None or not math.isfinite(float(value)) else format(value, fmt)


def summary_table(outcomes: list[SceneOutcome]) -> str:
    """A Markdown table: scene, status, steps, train s, PSNR, mIoU, out dir (or error and log).

    Columns are padded so the table also reads as plain text; a missing value is ``-``.
    """
    header = ["scene", "status", "steps", "train s", "PSNR", "mIoU", "out dir / error"]
    rows = []
    for o in outcomes:
        if o.ok:
            where = str(o.out_dir)
            if o.warnings:
                where += f" ({len(o.warnings)} warning{'s' if len(o.warnings) > 1 else ''}, see {LOG_NAME})"
        else:
            where = f"{o.error_type}: {_first_line(o.error)}" + (f" (log: {o.log})" if o.log else "")
        m = o.metrics
        steps = str(m["steps"]) if "steps" in m else "-"
        rows.append(
            [o.scene, o.status, steps, _number(m, "train_seconds", ".1f"), _number(m, "psnr", ".2f"),
             _number(m, "miou", ".3f"), where]
        )
    rows = [[_cell(c) for c in row] for row in rows]
    widths = [max(len(r[j]) for r in [header, *rows]) for j in range(len(header))]
    right = {2, 3, 4, 5}  # numbers

    def line(cells: list[str]) -> str:
        padded = [c.rjust(w) if j in right else c.ljust(w) for j, (c, w) in enumerate(zip(cells, widths))]
        return "| " + " | ".join(padded) + " |"

    rule = "|" + "|".join(("-" * (w + 1) + ":") if j in right else "-" * (w + 2) for j, w in enumerate(widths)) + "|"
    return "\n".join([line(header), rule, *(line(r) for r in rows)])


def write_summary(outcomes: list[SceneOutcome], out_root: str | Path) -> tuple[Path, Path]:
    """Write ``summary.md`` (the table, :func:`summary_table`) and ``summary.json`` into ``out_root``."""
    out_root = Path(out_root)
    n_ok = sum(o.ok for o in outcomes)
    text = (
        f"# scenelabel build: {n_ok} of {len(outcomes)} scenes built\n\n"
        + summary_table(outcomes)
        + f"\n\nEach scene's folder holds its {LOG_NAME} (progress, warnings, the traceback of a failure).\n"
    )
    data = {
        "scenelabel_version": __version__,
        "n_scenes": len(outcomes),
        "n_ok": n_ok,
        "n_failed": len(outcomes) - n_ok,
        "scenes": [o.to_dict() for o in outcomes],
    }
    md = atomic_write_bytes(out_root / SUMMARY_MD, text.encode())
    js = atomic_write_bytes(out_root / SUMMARY_JSON, json.dumps(data, indent=2, default=float).encode())
    return md, js
