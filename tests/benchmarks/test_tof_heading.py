"""The ToF heading benchmark lines up the ranges with the true pose and model: with the bench's
range errors switched off, what is left is the sensor's whole-millimetre rounding."""

from __future__ import annotations

import json

import pytest

from benchmarks import tof_heading
from tiplog.cli import main as tiplog_main

pytestmark = pytest.mark.slow

NO_ERRORS = ("tof.noise_sd_mm=0", "tof.pose_sd_mm=0", "tof.repeat_sd_mm=0", "tof.dropout_prob=0")


def _session(path, *sets):
    args = ["sim", "generate", "--scenario", "sweeps", "--seed", "5", "--duration", "12", "--out", str(path), "--quiet"]
    for s in sets:
        args += ["--set", s]
    assert tiplog_main(args) == 0
    return path


def test_without_range_errors_only_the_rounding_is_left(tmp_path, capsys):
    clean = _session(tmp_path / "clean.mcap", *NO_ERRORS)
    noisy = _session(tmp_path / "noisy.mcap")
    out = tmp_path / "rows.json"
    assert tof_heading.main([str(clean), str(noisy), "--json", str(out)]) == 0
    rows = {r["session"]: r for r in json.loads(out.read_text())}
    assert set(rows) == {"clean.mcap", "noisy.mcap"}
    c, n = rows["clean.mcap"], rows["noisy.mcap"]
    assert c["ranges"] > 300
    assert c["error_rms_mm"] < 0.6  # rounding to whole mm: 0.29 mm RMS
    assert n["error_rms_mm"] > 2.0  # 3.2 mm white noise and a 3 mm pose-locked error
    # a deeper tip is nearer the plane: the range falls with the depth, more than 1:1 (oblique beam)
    assert -3.0 < c["depth_mm_per_mm"][0] < -1.0
    assert abs(c["heading_mm_per_deg"][0]) > 0.5
    assert abs(c["fit_heading_deg"]) < 2.0 and abs(c["fit_depth_mm"]) < 4.0  # the true pose fits
    assert "clean.mcap / sweep_pitch" in capsys.readouterr().out


def test_a_recording_without_the_truth_is_one_line_and_status_2(tmp_path, capsys):
    src = _session(tmp_path / "s.mcap", "tof.dropout_prob=0")
    from tests.services.fusion.sessions import rewrite

    dst = tmp_path / "no_truth.mcap"
    rewrite(src, dst, lambda t: True, lambda name: name != "calibration_truth")
    assert tof_heading.main([str(dst)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calibration_truth" in err[0]
