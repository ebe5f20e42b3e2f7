"""`tiplog evaluate --paper --quick` end to end as a user runs it (a real subprocess making its
own bench sessions, a process pool): every report key, every table, the plots, the wall time;
and an existing report folder is refused without --force."""

from __future__ import annotations

import json

from study.paper import gather
from study.paper_report import ablation_md, markdown
from tiplog.cli import main as tiplog_main


def test_an_existing_report_folder_is_refused_without_force(tmp_path, capsys):
    out = tmp_path / "rep"
    out.mkdir()
    assert tiplog_main(["evaluate", "--paper", "--quick", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--force" in err[0] and str(out) in err[0]
    assert list(out.iterdir()) == []  # nothing generated


def test_a_failed_step_is_reported_not_fatal():
    res = {
        "wall_time_s": 12.0,
        "jobs": 2,
        "seed": 1,
        "quick": True,
        "sessions": {},
        "errors": {"translation": "UserError: no trials"},
        "dynamic": {},
        "subsets": {},
        "degraded": {},
    }
    md = markdown(res)
    assert "Wall time: 12 s" in md.splitlines()[2]
    assert "_Not measured: UserError: no trials_" in md
    assert "| translation.rmse_mm | ≤ 1.21 | n/a | no |" in md


def test_ablations_say_which_calibration_they_ran_with():
    row = {"kind": "subset", "tip_rmse_mm": 1.0, "tip_p95_mm": 2.0, "block_mean_mm": 1.0, "coverage": 1.0, "resets": 0}
    short = {**row, "tip_rmse_mm": 40.0, "coverage": 0.62}  # published nothing for 38 % of the time
    results = {
        "ablation:sweeps:full": row,
        "ablation:sweeps:imu_tof": short,
        "as_calibrated:sweeps": {**row, "tip_rmse_mm": 1.5},
    }
    on_file = gather(results, {})
    assert on_file["dynamic"]["sweeps"]["calibrated"]["tip_rmse_mm"] == 1.0
    assert on_file["dynamic"]["sweeps"]["as_calibrated"]["tip_rmse_mm"] == 1.5
    fallback = gather(results, {"calibrate": "UserError: no poses"}, "as_calibrated")
    assert "calibrated" not in fallback["dynamic"]["sweeps"] and fallback["ablations_calibration"] == "as_calibrated"
    assert fallback["subsets"]["full"]["tip_rmse_mm"]["sweeps"] == 1.0
    md = "\n".join(ablation_md(on_file))
    assert "| imu_tof | 40.00 (covers 62 %) [2.00]" in md  # a cell scored over part of the time says so
    assert "| full | 1.00 [2.00]" in md


def test_the_subsets_are_compared_block_by_block():
    def row(rmse, **blocks):
        return {
            "kind": "subset", "tip_rmse_mm": rmse, "tip_p95_mm": 2 * rmse, "block_mean_mm": rmse, "coverage": 1.0,
            "resets": 0, "blocks": [{"name": n, "tip_rmse_mm": v} for n, v in blocks.items()],
        }  # fmt: skip

    results = {
        "ablation:sweeps:full": row(0.8, sweep_pitch=0.81, sweep_roll=0.79),
        "ablation:sweeps:imu_vision": row(0.85, sweep_pitch=0.90, sweep_roll=0.75),
        "ablation:sweeps:imu_tof": row(40.0, sweep_pitch=30.0, sweep_roll=50.0),
        "ablation:teleop:full": row(0.9, teleop1=0.9),
        "ablation:teleop:imu_vision": row(0.9, teleop1=0.9),  # a tie goes to full fusion
        "ablation:teleop:imu_tof": row(20.0, teleop1=20.0),
    }
    res = gather(results, {})
    assert res["subsets"]["full"]["block_rmse_mm"] == {"sweep_pitch": 0.81, "sweep_roll": 0.79, "teleop1": 0.9}
    md = "\n".join(ablation_md(res))
    assert "| sweep_pitch | 30.000 | 0.900 | 0.810 | full |" in md
    assert "| sweep_roll | 50.000 | 0.750 | 0.790 | imu_vision |" in md
    assert "| teleop1 | 20.000 | 0.900 | 0.900 | full |" in md
    assert "best combination in 2 of 3 blocks (the paper: all seven); it loses sweep_roll by 0.040 mm" in md
    # without per-block results (an older report) the table is left out, not filled with n/a
    for r in results.values():
        del r["blocks"]
    assert "best combination" not in "\n".join(ablation_md(gather(results, {})))


def test_a_loss_says_whether_it_is_beyond_the_block_bootstrap():
    import numpy as np

    t = np.arange(0, 96_000, 5, dtype=np.int64) * 1_000_000  # a scored block at 200 Hz
    base = 0.7 + 0.2 * np.sin(t * 1e-9)
    burst = base + 4.0 * ((t >= 40 * 10**9) & (t < 40 * 10**9 + 600 * 10**6))  # one 0.6 s stretch worse

    def row(errors):
        blocks = [{"name": n, "tip_rmse_mm": float(np.sqrt(np.mean(e**2)))} for n, e in errors.items()]
        rmse = float(np.mean([b["tip_rmse_mm"] for b in blocks]))
        return {
            "kind": "subset", "tip_rmse_mm": rmse, "tip_p95_mm": 2 * rmse, "block_mean_mm": rmse, "coverage": 1.0,
            "resets": 0, "blocks": blocks, "_block_errors": {n: (t, e) for n, e in errors.items()},
        }  # fmt: skip

    results = {
        "ablation:sweeps:full": row({"sweep_pitch": 0.95 * base, "sweep_roll": 1.05 * base}),
        "ablation:sweeps:imu_vision": row({"sweep_pitch": base, "sweep_roll": base}),
        "ablation:teleop:full": row({"teleop1": burst}),
        "ablation:teleop:imu_vision": row({"teleop1": base}),
    }
    res = gather(results, {})
    vs = res["subsets"]["full"]["block_vs_best"]
    assert {b: (c["against"], c["resolved"]) for b, c in vs.items()} == {
        "sweep_pitch": ("imu_vision", 1), "sweep_roll": ("imu_vision", 1), "teleop1": ("imu_vision", 0)
    }  # fmt: skip
    assert vs["sweep_pitch"]["diff_mm"] < 0 < vs["sweep_roll"]["diff_mm"]
    md = "\n".join(ablation_md(res))
    assert "it loses sweep_roll by 0.036 mm to imu_vision (beyond the block bootstrap's 95 % interval" in md
    assert "teleop1 by 0.0" in md and "to imu_vision (within the block bootstrap's 95 % interval" in md
    assert "better than full fusion beyond the 95 % interval of a block bootstrap (the block's 2 s segments " in md
    assert "drawn with replacement) in 1 of 3 blocks" in md
    from study.evaluation import public

    assert "_block_errors" not in json.dumps(public(res))  # the errors stay out of report.json


def test_the_blackout_rows_say_how_many_and_the_papers_placement_comes_first():
    row = {"kind": "degraded", "tip_rmse_mm": 1.0, "tip_p95_mm": 2.0, "block_mean_mm": 1.0, "coverage": 1.0}
    results = {}
    for scen, shared in (("sweeps", 7), ("teleop", 9)):  # finished in any order: per session first here
        results[f"ablation:{scen}:blackout10_per_session"] = {**row, "resets": 0, "blackouts": 16}
        results[f"ablation:{scen}:third"] = {**row, "resets": 0}
        results[f"ablation:{scen}:blackout10"] = {**row, "resets": 0, "blackouts": shared, "block_mean_mm": 1.5}
    res = gather(results, {})
    assert res["degraded"]["blackout10"]["blackouts"] == {"sweeps": 7, "teleop": 9}
    md = "\n".join(ablation_md(res))
    assert "(7 in the programmed session, 9 in the teleoperated)" in md
    names = [ln.split("|")[1].strip() for ln in md.splitlines() if ln.startswith("| ") and "(" in ln]
    assert names[-3:] == ["third", "blackout10", "blackout10_per_session"]
