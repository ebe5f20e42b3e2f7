"""A module's cached kernels are dropped when a file they compile in changes (numba itself keys
the cache on the module's own file only), and kept otherwise; every module of the filter's
kernels records the digest of all the files they compile in."""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path

from services.fusion.eskf import kernels, models
from services.fusion.eskf.jit_cache import ESKF, cache_of, digest, drop_stale, sources


def _cache(folder, names):
    folder.mkdir(exist_ok=True)
    for n in names:
        (folder / n).write_bytes(b"x")


def test_cached_kernels_go_when_a_dependency_changes_and_stay_otherwise(tmp_path):
    dep = tmp_path / "so3.py"
    dep.write_text("A = 1\n")
    cache = tmp_path / "__pycache__"
    ours = ["steps.gyro_step-30.py311.nbi", "steps.gyro_step-30.py311.1.nbc"]
    theirs = ["stepsx.f-1.py311.nbi", "so3.exp_into-40.py311.nbi", "so3.exp_into-40.py311.1.nbc"]
    _cache(cache, ours + theirs)
    # no digest recorded yet (a cache older than the record): dropped once, then recorded
    assert drop_stale(cache, "steps", digest([dep])) is True
    assert sorted(p.name for p in cache.iterdir()) == sorted(["steps.deps", *theirs])
    _cache(cache, ours)  # compiled again
    assert drop_stale(cache, "steps", digest([dep])) is False  # the same source: kept
    assert all((cache / n).exists() for n in ours)
    dep.write_text("A = 2\n")  # an edit of the dependency alone
    assert drop_stale(cache, "steps", digest([dep])) is True
    assert not any((cache / n).exists() for n in ours) and all((cache / n).exists() for n in theirs)
    assert drop_stale(cache, "steps", digest([dep])) is False


def test_a_folder_that_cannot_be_written_is_left_as_it_is(tmp_path):
    dep = tmp_path / "layout.py"
    dep.write_text("N = 16\n")
    blocked = tmp_path / "file"
    blocked.write_text("")  # a file where the cache folder would be
    assert drop_stale(blocked / "__pycache__", "steps", digest([dep])) is False


def test_the_sources_are_every_kernel_and_model_module_and_the_layout():
    names = {p.relative_to(ESKF).as_posix() for p in sources()}
    assert {"layout.py", "kernels/so3.py", "kernels/steps.py", "models/rcm.py", "models/vision.py"} <= names
    assert {p.relative_to(ESKF).as_posix() for p in ESKF.glob("*/*.py")} <= names | {"__pycache__"}
    assert not {"filter.py", "params.py", "jit_cache.py"} & names


def test_an_edit_of_any_source_drops_every_modules_kernels(tmp_path):
    """A copy of the package's sources, each kernel module's cache folder holding its cached
    kernels and its record of the sources' digest: an edit of one module alone (models/tof.py)
    drops every module's cached kernels, its own and those of the modules that compile it in;
    with no edit they all stay."""
    for f in sources():
        c = tmp_path / f.relative_to(ESKF)
        c.parent.mkdir(parents=True, exist_ok=True)
        c.write_bytes(f.read_bytes())
    stems = [
        (c.parent / "__pycache__", c.stem) for c in sources(tmp_path) if c.name not in ("__init__.py", "layout.py")
    ]
    assert len(stems) >= 10

    def cached():
        for folder, stem in stems:
            _cache(folder, [f"{stem}.k-1.py311.nbi", f"{stem}.k-1.py311.1.nbc"])

    cached()
    assert all(drop_stale(folder, stem, digest(sources(tmp_path))) for folder, stem in stems)  # first record
    cached()
    assert not any(drop_stale(folder, stem, digest(sources(tmp_path))) for folder, stem in stems)  # kept
    tof = tmp_path / "models" / "tof.py"
    tof.write_text(tof.read_text() + "\n# an edit\n")
    assert all(drop_stale(folder, stem, digest(sources(tmp_path))) for folder, stem in stems)
    assert not any(any(folder.glob("*.nb?")) for folder, _ in stems)


def test_every_kernel_module_records_the_digest_of_the_sources():
    """Each module of the filter's kernels, once imported, has recorded the digest of all the
    sources beside its cache (its first kernel's `njit` did)."""
    now = digest(sources())
    seen = set()
    for pkg in (kernels, models):
        for info in pkgutil.iter_modules(pkg.__path__):
            mod = importlib.import_module(f"{pkg.__name__}.{info.name}")
            own = [
                d for d in vars(mod).values() if getattr(d, "py_func", None) and d.py_func.__module__ == mod.__name__
            ]
            where = cache_of(own[0]) if own else None
            if where is None:  # numpy only (vision), or numba disabled: nothing cached
                continue
            assert Path(where[0], f"{where[1]}.deps").read_text() == now, mod.__name__
            seen.add(mod.__name__)
    assert len(seen) >= 10 or not seen, seen
