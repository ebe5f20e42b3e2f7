"""`tiplog evaluate --paper --quick` end to end as a user runs it (a real subprocess making its
own bench sessions, a process pool): every report key, every table, the plots, the wall time."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from study.ablation import DEGRADED, SUBSETS
from study.paper_report import PAPER_TRANSLATION_STEPS


@pytest.mark.slow
def test_paper_quick_end_to_end(tmp_path):
    out = tmp_path / "paper"
    cmd = [sys.executable, "-m", "tiplog.cli", "evaluate", "--paper", "--quick", "--out", str(out), "--jobs", "2"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    # 7 protocol/calibration tasks, 4 after calibrate, and every subset and degradation on both
    # sessions, the blackouts twice (shared over the two sessions as the paper's, and per session)
    n = 11 + 2 * len(SUBSETS) + 2 * len(DEGRADED) + 2 * 3
    assert "generating 8 bench sessions" in r.stdout and f"{n}/{n}" in r.stdout  # progress lines
    rep = json.loads((out / "report.json").read_text())
    assert rep["errors"] == {}, rep["errors"]
    assert rep["wall_time_s"] > 0 and rep["quick"] is True
    t, rot = rep["translation"], rep["rotation"]
    assert 0 < t["rmse_mm"] < 5 and 0.5 < t["scale"] < 1.5 and t["all"]["ci95"][0] <= t["rmse_mm"]
    assert any(s["held_out"] for s in t["per_step"].values()) or set(t["per_step"]) <= {"5", "10", "20"}
    assert 0 < rot["angle_rmse_deg"] and 0 < rot["relrot_rmse_deg"] and 0 < rot["tip_rmse_mm"]
    assert rep["rotation_calibrated"]["relrot_rmse_deg"] > 0 and rep["translation_calibrated"]["rmse_mm"] > 0
    assert (out / "calibration_rotation.yaml").exists()
    for scen in ("sweeps", "teleop"):
        for name in SUBSETS:
            assert rep["subsets"][name]["tip_rmse_mm"][scen] > 0
        for name in DEGRADED:
            assert rep["degraded"][name]["tip_rmse_mm"][scen] > 0
        for name in ("blackout1", "blackout3", "blackout10"):
            assert rep["degraded"][f"{name}_per_session"]["blackouts"][scen] == 16
        assert rep["dynamic"][scen]["calibrated"]["tip_rmse_mm"] > 0
    # the paper's sixteen, shared over the two sessions in proportion to their blocks
    shared = rep["degraded"]["blackout1"]["blackouts"]
    assert shared["sweeps"] + shared["teleop"] == 16 and 0 < shared["sweeps"] < 16
    assert rep["latency"] and rep["stability"]["holds"] and rep["magnetometer"]["rotation"]["trials"] > 0
    assert rep["calibration"]["report"] and (out / "calibration.yaml").exists()
    md = (out / "report.md").read_text()
    assert md.splitlines()[2].startswith("Wall time:")
    for title in ("Static stability", "Observation latency", "Translation", "Rotation", "Magnetometer", "Dynamic"):
        assert f"## {title}" in md
    assert f"{PAPER_TRANSLATION_STEPS['All'][0]:.2f} [" in md  # the paper's figure beside ours
    blocks = rep["subsets"]["full"]["block_rmse_mm"]  # --quick's 40 s sessions hold one block each
    assert set(blocks) >= {"sweep_pitch", "teleop1"} and set(rep["subsets"]["imu_vision"]["block_rmse_mm"]) == set(
        blocks
    )
    assert "Full fusion is the best combination in " in md and f" of {len(blocks)} blocks" in md
    vs = rep["subsets"]["full"]["block_vs_best"]
    assert set(vs) == set(blocks) and all(c["low_mm"] <= c["diff_mm"] <= c["high_mm"] for c in vs.values())
    assert "better than full fusion beyond the 95 % interval of a block bootstrap" in md
    for png in ("translation_boxplots.png", "rotation_boxplots.png", "ablations.png", "sweep_pitch.png"):
        assert (out / png).stat().st_size > 5_000
