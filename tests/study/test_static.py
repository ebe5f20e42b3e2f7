"""Translation and rotation protocol metrics: the statistics on known errors, and the whole
evaluation on short bench sessions (the static-trial filter against the robot)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from study.static import bootstrap_rmse_ci, main, robot_windows, scale, summary
from study.static_filter import StaticParams
from study.static_trials import estimate_trials
from tiplog.cli import main as tiplog_main
from tiplog.geometry import rotation_angle


def test_summary_bootstrap_and_scale_on_known_errors():
    rng = np.random.default_rng(0)
    err = np.abs(rng.normal(size=400)) * 2.0
    s = summary(err)
    assert s["rmse"] == pytest.approx(np.sqrt(np.mean(err**2)))
    assert s["ci95"][0] < s["rmse"] < s["ci95"][1]
    assert s["ci95"][1] - s["ci95"][0] < 0.5  # 400 trials pin the RMSE to a few tenths
    lo, hi = bootstrap_rmse_ci(np.full(10, 3.0))
    assert lo == hi == pytest.approx(3.0)
    true = np.array([1.0, 2.0, 5.0, 10.0, 20.0])
    assert scale(0.962 * true, true) == pytest.approx(0.962)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("static")
    out = {}
    for scen, dur in (("translation", "70"), ("rotation", "70")):
        out[scen] = d / f"{scen}.mcap"
        assert (
            tiplog_main(
                ["sim", "generate", "--scenario", scen, "--out", str(out[scen]), "--seed", "5", "--duration", dur]
            )
            == 0
        )
    return out


@pytest.mark.slow
def test_translation_keys_and_plausible_accuracy(sessions, tmp_path, capsys):
    res = tmp_path / "t.json"
    assert main([str(sessions["translation"]), "--json", str(res)]) == 0
    t = json.loads(res.read_text())["translation"]
    assert 0.0 < t["rmse_mm"] < 3.0  # paper: 1.21 mm
    assert 0.8 < t["scale"] < 1.2
    assert all(set(r) >= {"n", "rmse", "ci95", "median", "p95", "held_out"} for r in t["per_step"].values())
    assert "| All |" in capsys.readouterr().out
    assert main([str(sessions["translation"]), "--json", str(res)]) == 2  # exists, no --force


@pytest.mark.slow
def test_rotation_keys_and_plausible_accuracy(sessions, tmp_path):
    res = tmp_path / "r.json"
    assert main([str(sessions["rotation"]), "--json", str(res)]) == 0
    r = json.loads(res.read_text())["rotation"]
    assert 0.0 < r["relrot_rmse_deg"] < 2.0  # paper: 0.341 deg
    # |angle(R1) - angle(R2)| <= angle(R1 R2^T): the angle error never exceeds the relative one
    assert 0.0 < r["angle_rmse_deg"] <= r["relrot_rmse_deg"] + 1e-9
    assert 0.0 < r["tip_rmse_mm"] < 5.0
    assert 0.9 < r["gain"] < 1.1


@pytest.mark.slow
def test_the_gyro_link_lowers_the_relative_rotation_error(sessions):
    """The blend of the post window's attitude with the pre window's carried by the gyro,
    against the filter's own post-window attitude, on the same trials (truth read here only)."""
    path = sessions["rotation"]

    def relrot(params):
        est, _ = estimate_trials(path, None, params)
        truth = robot_windows(path, est)
        Rt = np.array([b[1] @ a[1].T for a, b in truth])
        Re = np.array([e.R_rel for e in est])
        return float(np.sqrt(np.mean(np.degrees(rotation_angle(np.einsum("nij,nkj->nik", Re, Rt))) ** 2)))

    blended, own = relrot(StaticParams()), relrot(StaticParams(relrot_absolute_deg=0.0))
    assert blended < 0.9 * own, (blended, own)
