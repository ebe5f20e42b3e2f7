"""numba keys a module's cached kernels on that module's own file (its modification time and
size), not on the files whose functions and constants they compile in: after an edit of
`so3.py` or `layout.py` alone, `kernels.py`'s cached machine code would still load, built from
the old source, with no error. `drop_stale` removes a module's cached kernels when a digest of
those other files differs from the one recorded beside the cache, so that they compile anew."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from pathlib import Path


def digest(files: Sequence[str | os.PathLike]) -> str:
    h = hashlib.sha256()
    for f in files:
        h.update(Path(f).read_bytes())
    return h.hexdigest()


def drop_stale(cache_dir: str | os.PathLike, stem: str, deps: Sequence[str | os.PathLike]) -> bool:
    """Remove `stem`'s numba cache files (`stem.*.nbi`, `stem.*.nbc`) in `cache_dir` when the
    digest of `deps` is not the one recorded there (`stem.deps`), then record it. Returns
    whether files were removed. Quiet where the folder cannot be read or written (a read-only
    install keeps what it has)."""
    folder = Path(cache_dir)
    stamp = folder / f"{stem}.deps"
    try:
        now = digest(deps)
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


def drop_stale_for(dispatcher, deps: Sequence[str | os.PathLike]) -> bool:
    """`drop_stale` for the module of a numba dispatcher compiled with cache=True, in the folder
    numba caches it in (beside the module, or under NUMBA_CACHE_DIR). False where numba is
    absent or disabled (a plain function) or its cache layout is not the one known here."""
    try:
        cache_dir = dispatcher._cache._cache_path
        stem = Path(dispatcher.py_func.__code__.co_filename).stem
    except AttributeError:
        return False
    return drop_stale(cache_dir, stem, deps)
