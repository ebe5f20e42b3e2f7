"""Fusion on a programmed sweep is at least as accurate with `tiplog calibrate block`'s file
as with the session's own `calibration_as_calibrated` metadata (same bench, same seed: the
fit-only block and the sweep share their as-calibrated constants)."""

from __future__ import annotations

import json

import pytest

from tiplog.cli import main

SEED = 4  # chosen before running; not a tuning (>= 1000) or reporting (1, 2, 3) seed


@pytest.mark.slow
def test_fusion_with_calibrate_output_is_at_least_as_accurate(tmp_path):
    fit, sweep, cal = tmp_path / "fit.mcap", tmp_path / "sweep.mcap", tmp_path / "cal.yaml"
    assert main(["sim", "generate", "--scenario", "fit", "--out", str(fit), "--seed", str(SEED)]) == 0
    assert main(["sim", "generate", "--scenario", "sweeps", "--out", str(sweep), "--seed", str(SEED), "--duration", "100"]) == 0
    assert main(["calibrate", "block", str(fit), "--out", str(cal)]) == 0
    rmse = {}
    for name, extra in (("as_calibrated", []), ("calibrate", ["--calibration", str(cal)])):
        est, res = tmp_path / f"{name}.mcap", tmp_path / f"{name}.json"
        assert main(["fusion", "run", str(sweep), "--out", str(est), "--quiet", *extra]) == 0
        assert main(["evaluate", str(sweep), "--estimate", str(est), "--json", str(res)]) == 0
        rmse[name] = json.loads(res.read_text())["pooled"]["tip_rmse_mm"]
    assert rmse["calibrate"] <= rmse["as_calibrated"] * 1.02, rmse
