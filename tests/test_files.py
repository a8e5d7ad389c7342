"""Atomic writes: a failure mid-write leaves the previous file and no temp file."""

import pytest

import scenelabel._files as files
from scenelabel._files import atomic_write_bytes


def test_write_and_replace(tmp_path):
    path = tmp_path / "a.bin"
    atomic_write_bytes(path, b"one")
    atomic_write_bytes(path, b"two")
    assert path.read_bytes() == b"two"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin"]


def test_a_failure_before_the_rename_keeps_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "map.pgm"
    atomic_write_bytes(path, b"old")

    def killed(src, dst):
        raise KeyboardInterrupt  # as if the process were interrupted between write and rename

    monkeypatch.setattr(files.os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_bytes(path, b"new, half written")
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.pgm"]
