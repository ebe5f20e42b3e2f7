"""Per-block comparison of two estimates (`paired_rmse_difference`, `fusion_accuracy
--compare`) and their pooled ratio (`paired_rmse_ratio`, `fusion_accuracy --ratio`): a
difference that runs through the whole block is resolved, one that rests on a single burst of
error is not, and only the samples both estimated count."""

from __future__ import annotations

import json

import numpy as np
import pytest

from study.evaluation import EvaluationError, paired_rmse_difference, paired_rmse_ratio

MS = 1_000_000


def _block(seconds: float = 96.0, rate_hz: int = 200, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Stamps and a positive, correlated error series (mm): an AR(1) over ~0.5 s around 0.7 mm."""
    n = int(seconds * rate_hz)
    t = np.arange(n, dtype=np.int64) * (1000 // rate_hz) * MS
    rng = np.random.default_rng(seed)
    a = np.exp(-1.0 / (0.5 * rate_hz))
    x = np.zeros((n, 3))
    w = rng.normal(0.0, 0.4 * np.sqrt(1 - a * a), (n, 3))
    for i in range(1, n):
        x[i] = a * x[i - 1] + w[i]
    return t, np.linalg.norm(x, axis=1) + 0.1


def test_a_difference_through_the_whole_block_is_resolved():
    t, e = _block()
    r = paired_rmse_difference(t, 1.05 * e, t, e)
    assert r["diff_mm"] > 0 and r["resolved"] == 1
    assert 0 < r["low_mm"] < r["diff_mm"] < r["high_mm"]
    assert r["segments"] == 48  # 96 s in 2 s segments
    r = paired_rmse_difference(t, e, t, 1.05 * e)
    assert r["diff_mm"] < 0 and r["resolved"] == 1 and r["high_mm"] < 0


def test_a_loss_that_rests_on_one_burst_is_within_the_bootstrap():
    t, e = _block()
    worse = e.copy()
    burst = (t >= 40_000 * MS) & (t < 40_600 * MS)  # 0.6 s of 3 mm more, inside one segment
    worse[burst] += 3.0
    r = paired_rmse_difference(t, worse, t, e)
    assert r["diff_mm"] > 0.01  # a loss on the block's figure
    assert r["low_mm"] <= 0 < r["high_mm"] and r["resolved"] == 0
    # spread through the block the same excess of mean square is a real difference
    spread = np.sqrt(e**2 + np.mean(worse**2 - e**2))
    assert paired_rmse_difference(t, spread, t, e)["resolved"] == 1


def test_only_the_samples_both_estimated_count():
    t, e = _block(20.0)
    late = t >= 5_000 * MS  # b began 5 s later; a's first 5 s were far off
    a = e.copy()
    a[~late] += 50.0
    r = paired_rmse_difference(t, a, t[late], e[late])
    assert r["diff_mm"] == pytest.approx(0.0, abs=1e-12)
    assert r["rmse_b_mm"] == pytest.approx(float(np.sqrt(np.mean(e[late] ** 2))))


@pytest.mark.parametrize(
    "kw, words",
    [({"segment_s": 0.0}, "segment_s 0.0"), ({"draws": 0}, "draws 0"), ({"level": 1.0}, "level 1.0")],
)
def test_settings_out_of_range_are_refused(kw, words):
    t, e = _block(10.0)
    with pytest.raises(EvaluationError, match=words):
        paired_rmse_difference(t, e, t, e, **kw)


def test_two_estimates_with_no_common_sample_are_refused():
    t, e = _block(10.0)
    with pytest.raises(EvaluationError, match="share no sample time"):
        paired_rmse_difference(t, e, t + 1, e)


def test_a_ratio_through_the_whole_block_clears_its_target_and_one_from_a_burst_ties():
    t, e = _block()
    r = paired_rmse_ratio(t, 2.2 * e, t, e, target=2.0)
    assert r["ratio"] == pytest.approx(2.2, rel=1e-9)
    assert r["low"] == pytest.approx(2.2, rel=1e-9) and r["high"] == pytest.approx(2.2, rel=1e-9)
    assert (r["above"], r["below"]) == (1, 0)
    assert paired_rmse_ratio(t, 1.8 * e, t, e, target=2.0)["below"] == 1
    # a ratio of 2.2 that rests on one 4 s burst of error in a (1.95 elsewhere): not shown above 2
    a = 1.95 * e
    burst = (t >= 40_000 * MS) & (t < 44_000 * MS)
    a[burst] = np.sqrt(a[burst] ** 2 + np.sum(4.84 * e**2 - a**2) / burst.sum())
    r = paired_rmse_ratio(t, a, t, e, target=2.0)
    assert r["ratio"] == pytest.approx(2.2, rel=1e-6)
    assert r["low"] < 2.0 < r["high"] and (r["above"], r["below"]) == (0, 0)
    assert r["rmse_a_mm"] == pytest.approx(float(np.sqrt(np.mean(a**2))))


def test_a_pooled_ratio_keeps_blocks_apart_and_needs_an_error_to_divide_by():
    t1, e1 = _block(20.0)
    t2, e2 = _block(20.0, seed=1)
    t = np.concatenate([t1, t2 + 100_000 * MS])  # two blocks 80 s apart
    e = np.concatenate([e1, e2])
    assert paired_rmse_ratio(t, 3 * e, t, e)["segments"] == 20
    with pytest.raises(EvaluationError, match="no error to divide by"):
        paired_rmse_ratio(t, e, t, 0 * e)
    with pytest.raises(EvaluationError, match="paired_rmse_ratio: segment_s 0.0"):
        paired_rmse_ratio(t, e, t, e, segment_s=0.0)


def test_the_benchmark_compares_blocks_and_tallies_them(tmp_path_factory, tmp_path, capsys):
    from benchmarks.fusion_accuracy import main
    from tests.services.fusion.sessions import bench_session

    session = bench_session(tmp_path_factory, "teleop", 11, 9.0)
    out = tmp_path / "r.json"
    args = [str(session), "--variants", "full,imu_vision", "--compare", "full:imu_vision", "--json", str(out)]
    args += ["--ratio", "imu_vision:full:2"]
    assert main(args) == 0
    rows = json.loads(out.read_text())
    runs = {r["variant"]: r for r in rows if "variant" in r}
    (cmp_row,) = [r for r in rows if "compare" in r]
    (ratio,) = [r for r in rows if "ratio_of" in r]
    assert ratio["ratio_of"] == "imu_vision:full"
    full_pooled = runs["full"]["pooled"]["tip_rmse_mm"]
    assert ratio["rmse_b_mm"] == pytest.approx(full_pooled, rel=1e-9)  # every block pooled
    assert ratio["ratio"] == pytest.approx(runs["imu_vision"]["pooled"]["tip_rmse_mm"] / full_pooled, rel=1e-9)
    assert ratio["low"] <= ratio["ratio"] <= ratio["high"] and ratio["target"] == 2.0
    assert cmp_row["compare"] == "full:imu_vision"
    for c, full, iv in zip(cmp_row["blocks"], runs["full"]["blocks"], runs["imu_vision"]["blocks"], strict=True):
        assert c["name"] == full["name"] == iv["name"]
        assert c["rmse_a_mm"] == pytest.approx(full["tip_rmse_mm"], rel=1e-9)  # same samples in both
        assert c["rmse_b_mm"] == pytest.approx(iv["tip_rmse_mm"], rel=1e-9)
        assert c["low_mm"] <= c["diff_mm"] <= c["high_mm"]
    n = len(cmp_row["blocks"])
    won = sum(c["diff_mm"] <= 0 for c in cmp_row["blocks"])
    assert f"full against imu_vision: better in {won} of {n} blocks" in capsys.readouterr().out


@pytest.mark.parametrize(
    "option, value",
    [
        ("--compare", "full:imu_tof"),
        ("--compare", "full"),
        ("--compare", "full:imu_vision:x"),
        ("--ratio", "full:imu_tof"),
        ("--ratio", "full"),
        ("--ratio", "full:imu_vision:two"),
        ("--ratio", "full:imu_vision:0"),
    ],
)
def test_a_comparison_of_variants_not_run_is_refused(tmp_path, capsys, option, value):
    from benchmarks.fusion_accuracy import main

    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "absent.mcap"), "--variants", "full,imu_vision", option, value])
    assert e.value.code == 2
    assert option in capsys.readouterr().err
