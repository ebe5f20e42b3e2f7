"""numba keys a module's cached kernels on that module's own file (its modification time and
size), not on the files whose functions and constants they compile in: a kernel compiles in
every kernel it calls from the other modules of `kernels/` and `models/`, and `layout.py`'s
constants, so after an edit of one of those alone the other modules' cached machine code would
still load, built from the old source, with no error. Every filter kernel is therefore compiled
through `njit` here, which drops its module's cached kernels once per process when the digest
of all those files (`sources`) differs from the one recorded beside the cache."""

from __future__ import annotations

import functools
import hashlib
import os
from collections.abc import Sequence
from pathlib import Path

try:  # a dependency; the fallback keeps the kernels importable where numba cannot be installed
    import numba
except ImportError:  # pragma: no cover - exercised where numba is absent
    numba = None

ESKF = Path(__file__).resolve().parent


def sources(root: Path = ESKF) -> list[Path]:
    """The files any filter kernel may compile in: every module of `kernels/` and `models/`,
    and `layout.py` (of the eskf package at `root`)."""
    return sorted([*(root / "kernels").glob("*.py"), *(root / "models").glob("*.py"), root / "layout.py"])


def digest(files: Sequence[str | os.PathLike]) -> str:
    h = hashlib.sha256()
    for f in files:
        h.update(Path(f).read_bytes())
    return h.hexdigest()


@functools.cache
def _sources_digest() -> str:
    return digest(sources())


def drop_stale(cache_dir: str | os.PathLike, stem: str, now: str) -> bool:
    """Remove `stem`'s numba cache files (`stem.*.nbi`, `stem.*.nbc`) in `cache_dir` when the
    sources' digest `now` is not the one recorded there (`stem.deps`), then record it. Returns
    whether files were removed. Quiet where the folder cannot be read or written (a read-only
    install keeps what it has)."""
    folder = Path(cache_dir)
    stamp = folder / f"{stem}.deps"
    try:
        if stamp.is_file() and stamp.read_text() == now:
            return False
        folder.mkdir(parents=True, exist_ok=True)
        dropped = False
        for f in [*folder.glob(f"{stem}.*.nbi"), *folder.glob(f"{stem}.*.nbc")]:
            f.unlink(missing_ok=True)
            dropped = True
        tmp = folder / f"{stem}.deps.{os.getpid()}"
        tmp.write_text(now)
        os.replace(tmp, stamp)  # atomic: processes importing at once agree
        return dropped
    except OSError:
        return False


def cache_of(dispatcher) -> tuple[str, str] | None:
    """(the folder numba caches a cache=True dispatcher's module in, beside the module or under
    NUMBA_CACHE_DIR; the module's file stem), or None where numba is absent or disabled (a
    plain function) or its cache layout is not the one known here."""
    try:
        return dispatcher._cache._cache_path, Path(dispatcher.py_func.__code__.co_filename).stem
    except AttributeError:
        return None


_checked: set[tuple[str, str]] = set()


def njit(*args, **kwargs):
    """numba's `njit`, for the filter's kernels: the first kernel of a module compiled with
    cache=True drops the module's cached kernels when `sources` changed (`drop_stale`), before
    any of them can load. Without numba, the function itself (plain Python: slow, same results)."""
    if numba is None:  # pragma: no cover - exercised where numba is absent
        return args[0] if args and callable(args[0]) else lambda f: f

    def wrap(f):
        d = numba.njit(**kwargs)(f)
        where = cache_of(d) if kwargs.get("cache") else None
        if where is not None and where not in _checked:
            _checked.add(where)
            drop_stale(*where, _sources_digest())
        return d

    return wrap(args[0]) if args and callable(args[0]) else wrap
