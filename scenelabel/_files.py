"""Atomic file writes: a killed or failing write leaves the previous file (or none), never half a file."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["atomic_write_bytes"]


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to a hidden temp sibling ``.{name}.tmp-{pid}``, then rename it onto ``path``.

    The rename is atomic on POSIX filesystems, so readers see the old content or the new, and a
    crash before it leaves at most the temp file (removed here on any exception). Returns ``path``.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
