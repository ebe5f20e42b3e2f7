"""`tiplog evaluate` by protocol: a translation or rotation session runs the static-trial filter
itself (no --estimate), a static session gives the stability table, and what cannot be
evaluated is one line naming the option or the session, exit 2, no file written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from study.holds import hold_windows
from tests.services.fusion.sessions import bench_session
from tiplog.cli import main as tiplog_main


def _one_line_error(capsys, argv: list[str], *words: str) -> None:
    assert tiplog_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for w in words:
        assert w in err[0], err[0]


def test_translation_protocol_keys_and_plots(tmp_path_factory, tmp_path):
    session = bench_session(tmp_path_factory, "translation", seed=31, duration_s=40.0)
    res, plots = tmp_path / "t.json", tmp_path / "plots"
    assert tiplog_main(["evaluate", str(session), "--json", str(res), "--plots", str(plots)]) == 0
    t = json.loads(res.read_text())["translation"]
    assert 0.0 < t["rmse_mm"] < 3.0  # paper: 1.21 mm
    assert 0.8 < t["scale"] < 1.2
    a = t["all"]
    assert a["n"] >= 3 and a["ci95"][0] <= a["rmse"] <= a["ci95"][1] and a["median"] <= a["p95"]
    assert t["rmse_mm"] == pytest.approx(a["rmse"])
    for step, r in t["per_step"].items():
        assert r["held_out"] == (float(step) in (1.0, 2.0))
    assert (plots / "translation_boxplots.png").stat().st_size > 5_000


def test_rotation_protocol_keys(tmp_path_factory, tmp_path):
    session = bench_session(tmp_path_factory, "rotation", seed=31, duration_s=40.0)
    res = tmp_path / "r.json"
    assert tiplog_main(["evaluate", str(session), "--json", str(res)]) == 0
    r = json.loads(res.read_text())["rotation"]
    assert 0.0 < r["angle_rmse_deg"] < 1.0  # paper 0.200
    assert 0.0 < r["relrot_rmse_deg"] < 1.5  # paper 0.341
    assert 0.0 < r["tip_rmse_mm"] < 3.0  # paper 0.76
    assert r["angle_rmse_deg"] <= r["relrot_rmse_deg"] + 1e-9  # the angle error is part of it


def test_static_holds_stability_matches_the_bench_noise(tmp_path_factory, tmp_path, capsys):
    session = bench_session(tmp_path_factory, "static", seed=31, duration_s=40.0)
    res = tmp_path / "s.json"
    assert tiplog_main(["evaluate", str(session), "--json", str(res)]) == 0
    s = json.loads(res.read_text())
    assert len(s["holds"]) >= 1 and s["per_pose"]
    h = s["holds"][0]
    assert 0.15 < h["accel_tilt_sd_deg"] < 0.8  # bench: 0.30-0.55 deg across holds
    assert 2.0 < h["tof_raw_sd_mm"] < 4.5  # bench: 2.95-3.43 mm
    assert h["robot_tip_sd_mm"] < 0.1  # the robot holds still
    assert 0.0 < h["fusion_jitter_mm"] < 2.0 and np.isfinite(h["fusion_drift_mm"])
    assert "| Pose |" in capsys.readouterr().out


def test_hold_windows_are_the_trimmed_post_windows_of_holds_only():
    trials = [
        {"index": 0, "kind": "hold", "axis": "pose1", "post_start": 2000, "post_end": 32000},
        {"index": 1, "kind": "hold", "axis": "pose2", "post_start": 40000, "post_end": 44000},  # too short
        {"index": 2, "kind": "translation", "axis": "x", "post_start": 0, "post_end": 30000},
        {"index": 3, "kind": "soak", "axis": "pose0", "post_start": 50000, "post_end": 350000},
    ]
    w = hold_windows(trials)
    assert [x["index"] for x in w] == [0, 3]
    assert w[0]["t0_ns"] == 2_300_000_000 and w[0]["t1_ns"] == 31_700_000_000


def test_what_cannot_be_evaluated_is_one_line(tmp_path_factory, tmp_path, capsys):
    trans = bench_session(tmp_path_factory, "translation", seed=31, duration_s=40.0)
    fit = bench_session(tmp_path_factory, "fit", seed=31, duration_s=6.0)
    out = str(tmp_path / "r.json")
    _one_line_error(capsys, ["evaluate", str(trans)], "--json")
    _one_line_error(capsys, ["evaluate", str(fit), "--json", out], "fit session", "tiplog calibrate")
    _one_line_error(capsys, ["evaluate", str(trans), "--json", out, "--estimate", str(trans)], "--estimate")
    _one_line_error(
        capsys, ["evaluate", str(trans), "--json", out, "--calibration", str(tmp_path / "no.yaml")], "no.yaml"
    )
    _one_line_error(capsys, ["evaluate", str(tmp_path / "none.mcap"), "--json", out], "none.mcap")
    _one_line_error(capsys, ["evaluate", "--json", out], "--paper")
    _one_line_error(capsys, ["evaluate", str(trans), "--paper"], "--paper")
    _one_line_error(capsys, ["evaluate", str(trans), "--json", out, "--jobs", "0"], "--jobs")
    _one_line_error(capsys, ["evaluate", str(trans), "--json", out, "--quick"], "only with --paper")
    assert not (tmp_path / "r.json").exists()
    (tmp_path / "r.json").write_text("{}")
    _one_line_error(capsys, ["evaluate", str(trans), "--json", out], "--force")
    assert (tmp_path / "r.json").read_text() == "{}"
