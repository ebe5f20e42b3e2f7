"""Files that several tests read, made once per test run even when pytest-xdist runs the suite on
several worker processes: the first worker that asks makes the file under a lock, the others wait
for it and read the same file."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Callable
from pathlib import Path

import pytest


def shared_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of this test run that every worker sees (a worker's base temp is a subfolder of
    the run's)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent
    d = base / "run-once"
    d.mkdir(exist_ok=True)
    return d


def run_once(tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], None]) -> Path:
    """The file `name` in the run's shared folder; `make(path)` writes it in the first process
    that asks, into a folder of its own, and it is renamed into place only when complete."""
    path = shared_dir(tmp_path_factory) / name
    with open(path.with_name(name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not path.exists():
            tmp = tmp_path_factory.mktemp("run-once") / name
            make(tmp)
            assert tmp.is_file(), f"{make} wrote no {tmp}"
            os.replace(tmp, path)
    return path
