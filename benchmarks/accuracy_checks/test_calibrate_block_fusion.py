"""Fusion on programmed sweeps is at least as accurate, on average over seeds, with `tiplog
calibrate block`'s file as with each session's own `calibration_as_calibrated` metadata (same
bench and seed: the fit-only block and the sweep share their as-calibrated constants).

On a single seed either can win: the as-calibrated constants' random errors sometimes cancel
other errors of the filter (seed 4 alone: 1.89 mm as-calibrated against 2.27 mm calibrated,
although the calibrated mounting and junction offset were the closer to the truth)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tiplog.cli import main

SEEDS = (4, 5, 6)  # chosen before running; not tuning (>= 1000) or reporting (1, 2, 3) seeds


@pytest.mark.slow
def test_fusion_with_calibrate_output_is_at_least_as_accurate_on_average(tmp_path):
    rmse: dict[str, list[float]] = {"as_calibrated": [], "calibrate": []}
    for seed in SEEDS:
        fit, sweep, cal = tmp_path / f"fit{seed}.mcap", tmp_path / f"sweep{seed}.mcap", tmp_path / f"cal{seed}.yaml"
        assert main(["sim", "generate", "--scenario", "fit", "--out", str(fit), "--seed", str(seed)]) == 0
        gen = ["sim", "generate", "--scenario", "sweeps", "--out", str(sweep), "--seed", str(seed), "--duration", "80"]
        assert main(gen) == 0
        assert main(["calibrate", "block", str(fit), "--out", str(cal)]) == 0
        for name, extra in (("as_calibrated", []), ("calibrate", ["--calibration", str(cal)])):
            est, res = tmp_path / f"{name}{seed}.mcap", tmp_path / f"{name}{seed}.json"
            assert main(["fusion", "run", str(sweep), "--out", str(est), "--quiet", *extra]) == 0
            assert main(["evaluate", str(sweep), "--estimate", str(est), "--json", str(res)]) == 0
            rmse[name].append(json.loads(res.read_text())["pooled"]["tip_rmse_mm"])
    assert np.mean(rmse["calibrate"]) <= np.mean(rmse["as_calibrated"]) * 1.02, rmse
