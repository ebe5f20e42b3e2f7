"""PNG plots of `tiplog metrics`: per segment the tip speed profile with the movements and the idle
threshold marked and the working volume (the tip path and its convex hull), and per-segment bars
of the main metrics with their intervals and the truth."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from services.fusion.skill import kinematics as kin
from services.fusion.skill.assess import METRICS, MetricsParams
from tiplog.plots import pyplot, save

BARS = ("path_length_mm", "depth_path_mm", "angular_path_deg", "working_volume_cm3", "idle_time_s",
        "movements", "ldlj", "sparc")  # fmt: skip


def _speed_plot(plt, name: str, est, truth, params: MetricsParams):
    rate = params.rate_hz
    v = kin.speed(kin.lowpass(est.p_tip_base_m, rate, params.speed_cutoff_hz), rate) * 1e3
    moves = kin.movements(
        v * 1e-3, rate, params.movement_speed_mmps * 1e-3, params.movement_min_s, params.movement_merge_s
    )
    fig, ax = plt.subplots(figsize=(11, 3.6))
    t = est.t_s - est.t_s[0]
    for a, b in moves:
        ax.axvspan(t[a], t[b - 1], color="tab:green", alpha=0.15, lw=0)
    if truth is not None and len(truth.t_s) > 10:
        vt = kin.speed(kin.lowpass(truth.p_tip_base_m, rate, params.speed_cutoff_hz), rate) * 1e3
        ax.plot(truth.t_s - est.t_s[0], vt, lw=0.7, color="0.5", label="robot")
    ax.plot(t, v, lw=0.8, color="tab:blue", label="estimate")
    ax.axhline(params.idle_speed_mmps, color="tab:red", lw=0.8, ls="--", label="idle threshold")
    ax.set_xlabel("time in segment [s]")
    ax.set_ylabel("tip speed [mm/s]")
    ax.set_title(f"{name}: tip speed, {len(moves)} movements (shaded)")
    ax.legend(loc="upper right")
    return fig


def _volume_plot(plt, name: str, est, value_cm3: float):
    from scipy.spatial import ConvexHull, QhullError

    p = kin.lowpass(est.p_tip_base_m, 100.0, 2.0) * 1e3 if len(est.t_s) > 20 else est.p_tip_base_m * 1e3
    fig = plt.figure(figsize=(6, 5.5))
    ax = fig.add_subplot(projection="3d")
    ax.plot(p[:, 0], p[:, 1], p[:, 2], lw=0.6)
    try:
        hull = ConvexHull(p)
        for simplex in hull.simplices:
            tri = p[np.append(simplex, simplex[0])]
            ax.plot(tri[:, 0], tri[:, 1], tri[:, 2], color="tab:orange", lw=0.2, alpha=0.5)
    except QhullError:
        pass
    ax.set_xlabel("base x [mm]")
    ax.set_ylabel("base y [mm]")
    ax.set_zlabel("base z [mm]")
    ax.set_title(f"{name}: working volume {value_cm3:.1f} cm3")
    return fig


def _bars(plt, res: dict[str, Any]):
    segs = res["segments"]
    fig, axes = plt.subplots(2, 4, figsize=(14, 6))
    x = np.arange(len(segs))
    for ax, key in zip(axes.ravel(), BARS, strict=True):
        vals = np.array([s["metrics"][key]["value"] for s in segs], dtype=float)
        lo = np.array([s["metrics"][key]["low"] if s["metrics"][key]["low"] is not None else np.nan for s in segs])
        hi = np.array([s["metrics"][key]["high"] if s["metrics"][key]["high"] is not None else np.nan for s in segs])
        ax.bar(x, vals, color="tab:blue", alpha=0.7, label="estimate")
        err = np.stack([np.clip(vals - lo, 0, None), np.clip(hi - vals, 0, None)])
        if np.any(np.isfinite(err)):
            ax.errorbar(x, vals, yerr=np.nan_to_num(err), fmt="none", ecolor="k", capsize=3)
        truth = [s["metrics"][key].get("truth") for s in segs]
        if any(t is not None for t in truth):
            ax.plot(x, [np.nan if t is None else t for t in truth], "o", color="tab:red", ms=4, label="robot")
        unit = METRICS[key][0]
        ax.set_title(f"{key}" + (f" [{unit}]" if unit else ""), fontsize=9)
        ax.set_xticks(x, [s["name"] for s in segs], rotation=30, fontsize=7)
    axes.ravel()[0].legend(fontsize=7)
    return fig


def write_plots(
    res: dict[str, Any], folder: Path, names: list[str], params: MetricsParams, force: bool = False
) -> list[Path]:
    """Write the files `names` (from `skill.cli.plot_names`) into `folder`."""
    plt = pyplot()
    out = []
    for i, (name, est, truth) in enumerate(res["_series"]):
        seg = res["segments"][i]
        out.append(save(_speed_plot(plt, name, est, truth, params), folder / names[2 * i], force))
        vol = seg["metrics"]["working_volume_cm3"]["value"]
        out.append(save(_volume_plot(plt, name, est, vol), folder / names[2 * i + 1], force))
    out.append(save(_bars(plt, res), folder / names[-1], force))
    return out
