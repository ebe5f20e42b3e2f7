"""Scoring an estimate against the bench's ground truth (evaluation only: the estimator never
sees any of this).

Continuous blocks (programmed sweeps, teleoperated, demo), as the paper scores them: the
absolute tip error at every estimated (IMU) sample in the robot base frame, no alignment, the
first 20 % of each block excluded; RMSE, median, p95, and the RMSE of the radial part (along
the true shaft, i.e. depth) and the tangential part (normal to it); per block and pooled, each
with its `coverage`: the share of the window the estimate covers (below 1 where the filter
published nothing for a while, which the error figures cannot show).
Other protocols (translation, rotation, static holds) register their own scorer in
`SCORERS` under their protocol name and reuse `load_truth` / `load_estimate`.

The estimate is `fusion/state` of a `tiplog fusion run` file, or of a live recording the
`fusion/state_settled` it holds (the same stream an offline run writes; its `fusion/state` is
the display stream, 30 ms behind): `estimate_topic` picks it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tiplog.mcap_io import read_messages, read_metadata, read_summary

CONTINUOUS_KINDS = ("sweep", "teleop", "demo")
CONTINUOUS_PROTOCOLS = ("sweeps", "teleop", "demo")
EXCLUDE_FRACTION = 0.2


class EvaluationError(ValueError):
    """A session or estimate that cannot be scored; the message says why."""


@dataclass
class Truth:
    t_ns: np.ndarray  # (n,)
    tip_base_m: np.ndarray  # (n, 3)
    rcm_base_m: np.ndarray  # (n, 3)
    trials: list[dict[str, Any]]
    protocol: str


@dataclass
class Estimate:
    t_ns: np.ndarray
    tip_base_m: np.ndarray


def read_trials(session: str | Path, md: dict[str, dict[str, str]] | None = None) -> list[dict[str, Any]]:
    """A bench session's `trials` metadata (its protocol's timing), from `md` if already read."""
    md = read_metadata(session) if md is None else md
    if "trials" not in md:
        raise EvaluationError(f"{session}: no 'trials' metadata (not a bench session with ground truth)")
    return json.loads(md["trials"]["json"])


def load_truth(session: str | Path) -> Truth:
    md = read_metadata(session)
    trials = read_trials(session, md)
    protocol = md.get("session", {}).get("protocol", "")
    t, tip, rcm = [], [], []
    for rec in read_messages(session, ["bench/robot"]):
        m = rec.message
        t.append(m.header.stamp_ns)
        tip.append((m.tip_m.x, m.tip_m.y, m.tip_m.z))
        rcm.append((m.rcm_m.x, m.rcm_m.y, m.rcm_m.z))
    if len(t) < 2:
        raise EvaluationError(f"{session}: no ground truth (topic bench/robot)")
    return Truth(np.asarray(t, np.int64), np.asarray(tip), np.asarray(rcm), trials, protocol)


SETTLED_TOPIC = "fusion/state_settled"


def estimate_topic(path: str | Path) -> str:
    """The topic to score in an estimate file: fusion/state_settled where it has one (a live
    recording), else fusion/state (a `tiplog fusion run` file)."""
    summary = read_summary(path)
    have = {c.topic for c in summary.channels.values()} if summary is not None else set()
    return SETTLED_TOPIC if SETTLED_TOPIC in have else "fusion/state"


def load_estimate(path: str | Path, topic: str = "fusion/state") -> Estimate:
    t, tip = [], []
    for rec in read_messages(path, [topic]):
        m = rec.message
        t.append(m.header.stamp_ns)
        tip.append((m.tip_m.x, m.tip_m.y, m.tip_m.z))
    if not t:
        raise EvaluationError(f"{path}: no estimate (topic {topic})")
    order = np.argsort(np.asarray(t), kind="stable")
    return Estimate(np.asarray(t, np.int64)[order], np.asarray(tip)[order])


def interp_columns(tq: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Each column of y (n, k), sampled at times t, linearly interpolated at times tq -> (len(tq), k)."""
    return np.stack([np.interp(tq, t, y[:, j]) for j in range(y.shape[1])], 1)


def error_stats(err_m: np.ndarray, radial_m: np.ndarray) -> dict[str, float]:
    """Tip error vectors (n, 3) [m] and their radial parts (n,) [m] -> figures in mm."""
    e = np.linalg.norm(err_m, axis=1) * 1e3
    rad = radial_m * 1e3
    tan = np.sqrt(np.maximum(e**2 - rad**2, 0.0))
    if len(e) == 0:
        return {k: float("nan") for k in _KEYS} | {"samples": 0}
    return {
        "tip_rmse_mm": float(np.sqrt(np.mean(e**2))),
        "tip_median_mm": float(np.median(e)),
        "tip_p95_mm": float(np.percentile(e, 95)),
        "radial_rmse_mm": float(np.sqrt(np.mean(rad**2))),
        "tangential_rmse_mm": float(np.sqrt(np.mean(tan**2))),
        "samples": int(len(e)),
    }


_KEYS = ("tip_rmse_mm", "tip_median_mm", "tip_p95_mm", "radial_rmse_mm", "tangential_rmse_mm")


COVERAGE_WARN = 0.99  # a block covered less than this is flagged wherever its figures are shown


def coverage_note(coverage: float | None, subject: str = "") -> str:
    """' (covers N %)' after a figure scored over less than COVERAGE_WARN of its time, else ''."""
    if coverage is None or coverage >= COVERAGE_WARN:
        return ""
    return f" ({subject}covers {100 * coverage:.0f} %)"


def nominal_period_ns(t_ns: np.ndarray) -> float:
    """The estimate's sample period: the median interval between its samples (0 for fewer
    than two)."""
    return float(np.median(np.diff(t_ns))) if len(t_ns) > 1 else 0.0


def _coverage(n: int, window_ns: int, period_ns: float) -> float:
    """Share of a scored window the estimate covers: its samples there against those a
    gapless estimate at its own period would have. A filter that published nothing for part of
    a block (waiting for vision after a reset) is scored only where it published: this says
    how much that is."""
    if window_ns <= 0 or period_ns <= 0:
        return float(n > 0)
    return float(min(1.0, n / (window_ns / period_ns)))


def block_windows(trials: list[dict[str, Any]]) -> list[tuple[str, int, int]]:
    """(name, start_ns, end_ns) of every continuous block, its first 20 % excluded."""
    out = []
    for tr in trials:
        kind = str(tr.get("kind", ""))
        if not kind.startswith(CONTINUOUS_KINDS):
            continue
        a, b = int(tr["move_start"]) * 1_000_000, int(tr["move_end"]) * 1_000_000
        if b <= a:
            continue
        out.append((kind, a + int(EXCLUDE_FRACTION * (b - a)), b))
    return out


def score_continuous(truth: Truth, est: Estimate) -> dict[str, Any]:
    """Per block and pooled tip error of `est` against `truth` (see the module docstring)."""
    windows = block_windows(truth.trials)
    if not windows:
        raise EvaluationError("no continuous blocks (sweeps, teleop, demo) in this session")
    lo, hi = truth.t_ns[0], truth.t_ns[-1]
    period = nominal_period_ns(est.t_ns)
    blocks, errs, rads, series = [], [], [], []
    for name, a, b in windows:
        sel = (est.t_ns >= a) & (est.t_ns <= b) & (est.t_ns >= lo) & (est.t_ns <= hi)
        t = est.t_ns[sel]
        p_true = interp_columns(t, truth.t_ns, truth.tip_base_m)
        r_true = interp_columns(t, truth.t_ns, truth.rcm_base_m)
        u = p_true - r_true
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        e = est.tip_base_m[sel] - p_true
        radial = (e * u).sum(1)
        stats = error_stats(e, radial)
        stats["coverage"] = _coverage(len(t), b - a, period)
        blocks.append({"name": name, **stats})
        errs.append(e)
        rads.append(radial)
        series.append((name, t, est.tip_base_m[sel], p_true, np.linalg.norm(e, axis=1)))
    pooled = error_stats(np.concatenate(errs), np.concatenate(rads))
    pooled["coverage"] = _coverage(pooled["samples"], sum(b - a for _, a, b in windows), period)
    return {"protocol": truth.protocol, "pooled": pooled, "blocks": blocks, "_series": series}


def block_errors_mm(series: list) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{block: (scored stamps, tip error norms in mm)} from `score_continuous`'s `_series`: what
    `paired_rmse_difference` compares."""
    return {name: (t, e * 1e3) for name, t, _, _, e in series}


def _paired_bootstrap(
    where: str, t_a_ns: np.ndarray, err_a_mm: np.ndarray, t_b_ns: np.ndarray, err_b_mm: np.ndarray,
    segment_s: float, draws: int, level: float, seed: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The block bootstrap `paired_rmse_difference` and `paired_rmse_ratio` share: per
    `segment_s` segment of the samples both estimated, (sample count, a's and b's sums of squared
    error), and `draws` rows of segment indices drawn with replacement. Stamps more than a
    segment apart (two blocks) never share one. Raises EvaluationError (naming `where`) for no
    common samples or a segment length, draw count or level out of range."""
    if not segment_s > 0 or draws < 1 or not 0 < level < 1:
        raise EvaluationError(f"{where}: segment_s {segment_s}, draws {draws}, level {level}")
    t, ia, ib = np.intersect1d(np.asarray(t_a_ns), np.asarray(t_b_ns), assume_unique=True, return_indices=True)
    if len(t) == 0:
        raise EvaluationError(f"{where}: the two estimates share no sample time")
    sq_a = np.asarray(err_a_mm, float)[ia] ** 2
    sq_b = np.asarray(err_b_mm, float)[ib] ** 2
    seg = ((t - t[0]) // int(segment_s * 1e9)).astype(np.int64)
    _, seg = np.unique(seg, return_inverse=True)
    k = int(seg.max()) + 1
    n = np.bincount(seg, minlength=k).astype(float)
    idx = np.random.default_rng(seed).integers(0, k, size=(draws, k))
    return n, np.bincount(seg, sq_a, minlength=k), np.bincount(seg, sq_b, minlength=k), idx


def paired_rmse_difference(
    t_a_ns: np.ndarray, err_a_mm: np.ndarray, t_b_ns: np.ndarray, err_b_mm: np.ndarray,
    segment_s: float = 2.0, draws: int = 2000, level: float = 0.95, seed: int = 0,
) -> dict[str, float]:  # fmt: skip
    """Whether estimate a's tip RMSE over a block is really above or below b's, or within what
    the block's own course of errors leaves open: rmse_a - rmse_b over the samples both
    estimated (the tip error norms `err_*_mm` at stamps `t_*_ns`), and its `level` interval
    from a block bootstrap: the samples cut into consecutive `segment_s` segments (the errors
    are correlated over a second or so: a filter's state error, the pose-locked sensor errors
    along the path, so single samples are far from independent), the segments drawn with
    replacement `draws` times, and the difference computed on each draw. `resolved` is 1 where
    the interval excludes zero (a difference the block shows, not one a different course of
    the same kind of motion could reverse), else 0. Raises EvaluationError for no common
    samples or a segment length, draw count or level out of range."""
    n, ss_a, ss_b, idx = _paired_bootstrap(
        "paired_rmse_difference", t_a_ns, err_a_mm, t_b_ns, err_b_mm, segment_s, draws, level, seed
    )
    n_d = n[idx].sum(1)
    diff_d = np.sqrt(ss_a[idx].sum(1) / n_d) - np.sqrt(ss_b[idx].sum(1) / n_d)
    lo, hi = np.quantile(diff_d, [(1 - level) / 2, (1 + level) / 2])
    rmse_a, rmse_b = float(np.sqrt(ss_a.sum() / n.sum())), float(np.sqrt(ss_b.sum() / n.sum()))
    return {
        "rmse_a_mm": rmse_a,
        "rmse_b_mm": rmse_b,
        "diff_mm": rmse_a - rmse_b,
        "low_mm": float(lo),
        "high_mm": float(hi),
        "resolved": int(lo > 0 or hi < 0),
        "segments": len(n),
    }


def paired_rmse_ratio(
    t_a_ns: np.ndarray, err_a_mm: np.ndarray, t_b_ns: np.ndarray, err_b_mm: np.ndarray, target: float = 1.0,
    segment_s: float = 2.0, draws: int = 2000, level: float = 0.95, seed: int = 0,
) -> dict[str, float]:  # fmt: skip
    """rmse_a / rmse_b over the samples both estimated, with the `level` interval of the same
    block bootstrap as `paired_rmse_difference` (segments drawn with replacement, the ratio
    computed on each draw): for targets stated as ratios ("at least twice the full fusion's").
    Pass several blocks' samples at once for a pooled ratio; a segment never spans two blocks
    more than `segment_s` apart. `above` / `below` are 1 where the whole interval lies above /
    below `target`; neither is a tie with it. Raises EvaluationError as
    `paired_rmse_difference`, and for b without error."""
    n, ss_a, ss_b, idx = _paired_bootstrap(
        "paired_rmse_ratio", t_a_ns, err_a_mm, t_b_ns, err_b_mm, segment_s, draws, level, seed
    )
    if not ss_b.sum() > 0:
        raise EvaluationError("paired_rmse_ratio: the second estimate has no error to divide by")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio_d = np.sqrt(ss_a[idx].sum(1) / ss_b[idx].sum(1))
    lo, hi = np.nanquantile(ratio_d, [(1 - level) / 2, (1 + level) / 2])
    return {
        "rmse_a_mm": float(np.sqrt(ss_a.sum() / n.sum())),
        "rmse_b_mm": float(np.sqrt(ss_b.sum() / n.sum())),
        "ratio": float(np.sqrt(ss_a.sum() / ss_b.sum())),
        "low": float(lo),
        "high": float(hi),
        "target": float(target),
        "above": int(lo > target),
        "below": int(hi < target),
        "segments": len(n),
    }


SCORERS: dict[str, Callable[[Truth, Estimate], dict[str, Any]]] = {
    "sweeps": score_continuous,
    "teleop": score_continuous,
    "demo": score_continuous,
}


def evaluate(session: str | Path, estimate: str | Path, topic: str | None = None) -> dict[str, Any]:
    """Score `estimate` (its `topic`; by default `estimate_topic`'s choice, named in the result)."""
    truth = load_truth(session)
    topic = topic or estimate_topic(estimate)
    est = load_estimate(estimate, topic)
    scorer = SCORERS.get(truth.protocol, score_continuous)
    return {"estimate_topic": topic, **scorer(truth, est)}


def plot(result: dict[str, Any], folder: Path, force: bool = True) -> list[Path]:
    """Per block: tip path (truth and estimate, the two base axes of largest spread) and the
    error over time, as PNG files in `folder` (an existing one replaced only with `force`)."""
    from tiplog.plots import pyplot, save

    plt = pyplot()
    out = []
    for name, t, p_est, p_true, e in result["_series"]:
        if len(t) == 0:
            continue
        ax_i = np.argsort(p_true.std(0))[::-1][:2]
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
        a1.plot(p_true[:, ax_i[0]] * 1e3, p_true[:, ax_i[1]] * 1e3, lw=0.8, label="robot")
        a1.plot(p_est[:, ax_i[0]] * 1e3, p_est[:, ax_i[1]] * 1e3, lw=0.8, label="estimate")
        a1.set_xlabel(f"base {'xyz'[ax_i[0]]} [mm]")
        a1.set_ylabel(f"base {'xyz'[ax_i[1]]} [mm]")
        a1.set_aspect("equal", adjustable="datalim")
        a1.legend()
        a1.set_title(f"{name}: tip path")
        a2.plot((t - t[0]) * 1e-9, e * 1e3, lw=0.6)
        a2.set_xlabel("time in scored window [s]")
        a2.set_ylabel("tip error [mm]")
        a2.set_title(f"RMSE {np.sqrt(np.mean(e**2)) * 1e3:.2f} mm")
        out.append(save(fig, folder / f"{name}.png", force))
    return out


def public(result: dict[str, Any]) -> dict[str, Any]:
    """The result without private keys (`_series`, `_errors`) at any level, NaN as null and
    numpy scalars as Python numbers (what goes into the JSON file)."""

    def clean(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items() if not str(k).startswith("_")}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, float) and not np.isfinite(v):
            return None
        return v

    return clean(result)
