"""PNG plots like the paper's figures: error boxplots per step and axis (translation, rotation)
and the subset / degraded-vision comparison as a bar chart. The continuous blocks' tip path and
error over time are `study.evaluation.plot`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tiplog.plots import pyplot, save


def _box(ax, data: list[np.ndarray], labels: list[str]) -> None:
    ax.boxplot(data)
    ax.set_xticks(range(1, len(labels) + 1), labels)


def protocol_boxplots(res: dict[str, Any], folder: Path, prefix: str = "", force: bool = True) -> list[Path]:
    """From `evaluate_static`'s result (with its private `_errors`): translation error per
    step and per axis; rotation relative-rotation and angle error per axis. Returns the files."""
    plt = pyplot()
    err = res.get("_errors")
    if not err or len(err["tip_mm"]) == 0:
        return []
    out = []
    axes = err["axis"]
    names = sorted(set(axes.tolist()))
    if "translation" in res:
        steps = np.abs(err["magnitude"])
        su = sorted(set(steps.tolist()))
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
        _box(a1, [err["tip_mm"][steps == s] for s in su], [f"{s:g}" for s in su])
        a1.set_xlabel("step [mm]")
        a1.set_ylabel("displacement error [mm]")
        a1.set_title(f"translation: RMSE {res['translation']['rmse_mm']:.2f} mm")
        _box(a2, [err["tip_mm"][axes == a] for a in names], names)
        a2.set_xlabel("axis (camera frame)")
        a2.set_ylabel("displacement error [mm]")
        out.append(save(fig, folder / f"{prefix}translation_boxplots.png", force))
    if "rotation" in res:
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
        _box(a1, [err["relrot_deg"][axes == a] for a in names], names)
        a1.set_ylabel("relative-rotation error [deg]")
        a1.set_title(f"rotation: rel. rot. RMSE {res['rotation']['relrot_rmse_deg']:.3f} deg")
        _box(a2, [np.abs(err["angle_deg"][axes == a]) for a in names], names)
        a2.set_ylabel("|rotation-angle error| [deg]")
        a2.set_title(f"angle RMSE {res['rotation']['angle_rmse_deg']:.3f} deg")
        out.append(save(fig, folder / f"{prefix}rotation_boxplots.png", force))
    return out


def ablation_bars(
    tables: dict[str, dict[str, Any]], folder: Path, name: str = "ablations.png", force: bool = True
) -> Path:
    """Bar chart of pooled tip RMSE per variant, one group of bars per session.
    `tables`: session label -> `ablation.ablation_table` result."""
    plt = pyplot()
    variants = []
    for t in tables.values():
        for key in ("subsets", "degraded"):
            variants += [v for v in t.get(key, {}) if v not in variants]
    fig, ax = plt.subplots(figsize=(max(7, 1.1 * len(variants)), 4.5))
    width = 0.8 / max(len(tables), 1)
    x = np.arange(len(variants))
    for i, (label, t) in enumerate(tables.items()):
        merged = t.get("subsets", {}) | t.get("degraded", {})
        y = [merged.get(v, {}).get("tip_rmse_mm") for v in variants]
        y = [np.nan if x is None else x for x in y]
        ax.bar(x + (i - (len(tables) - 1) / 2) * width, y, width, label=label)
    ax.set_xticks(x, variants, rotation=30, ha="right")
    ax.set_ylabel("pooled tip RMSE [mm]")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title("sensor subsets and degraded vision")
    return save(fig, folder / name, force)
