"""A module's cached kernels are dropped when a file they compile in changes (numba itself keys
the cache on the module's own file only), and kept otherwise."""

from __future__ import annotations

from services.fusion.eskf import kernels
from services.fusion.eskf.jit_cache import drop_stale, drop_stale_for


def _cache(folder, names):
    folder.mkdir(exist_ok=True)
    for n in names:
        (folder / n).write_bytes(b"x")


def test_cached_kernels_go_when_a_dependency_changes_and_stay_otherwise(tmp_path):
    dep = tmp_path / "so3.py"
    dep.write_text("A = 1\n")
    cache = tmp_path / "__pycache__"
    ours = ["kernels.gyro_step-387.py311.nbi", "kernels.gyro_step-387.py311.1.nbc"]
    theirs = ["so3.exp_into-40.py311.nbi", "so3.exp_into-40.py311.1.nbc"]
    _cache(cache, ours + theirs)
    # no digest recorded yet (a cache older than the record): dropped once, then recorded
    assert drop_stale(cache, "kernels", [dep]) is True
    assert sorted(p.name for p in cache.iterdir()) == sorted(["kernels.deps", *theirs])
    _cache(cache, ours)  # compiled again
    assert drop_stale(cache, "kernels", [dep]) is False  # the same source: kept
    assert all((cache / n).exists() for n in ours)
    dep.write_text("A = 2\n")  # an edit of the dependency alone
    assert drop_stale(cache, "kernels", [dep]) is True
    assert not any((cache / n).exists() for n in ours) and all((cache / n).exists() for n in theirs)
    assert drop_stale(cache, "kernels", [dep]) is False


def test_a_folder_that_cannot_be_written_is_left_as_it_is(tmp_path):
    dep = tmp_path / "layout.py"
    dep.write_text("N = 16\n")
    blocked = tmp_path / "file"
    blocked.write_text("")  # a file where the cache folder would be
    assert drop_stale(blocked / "__pycache__", "kernels", [dep]) is False


def test_the_filter_kernels_record_their_dependencies():
    if not hasattr(kernels.gyro_step, "_cache"):  # NUMBA_DISABLE_JIT: nothing cached
        return
    stamp = kernels.gyro_step._cache._cache_path + "/kernels.deps"
    with open(stamp) as f:
        recorded = f.read()
    from services.fusion.eskf import layout, so3
    from services.fusion.eskf.jit_cache import digest

    assert recorded == digest([so3.__file__, layout.__file__])
    assert drop_stale_for(kernels.gyro_step, [so3.__file__, layout.__file__]) is False
