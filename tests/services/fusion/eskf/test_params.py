"""The filter's parameter file as a user meets it: a value of the wrong kind (a quoted "false",
a fraction for a count, an infinite sigma) or an empty range is refused with one line naming
the parameter, never silently turned into something else."""

from __future__ import annotations

import pytest

from services.fusion.eskf.params import Params, ParamsError, parse_sensors
from services.fusion.params_file import load_params
from tiplog.cli import main
from tiplog.mcap_io import McapWriter


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        ('tof_map: "false"', ("tof_map", "true or false", "'false'")),
        ("tof_map: maybe", ("tof_map", "true or false", "'maybe'")),
        ("tof_map: 5", ("tof_map", "true or false", "5")),
        ("gated_out_tip: 0", ("gated_out_tip", "true or false")),
        ("rcm_every: 2.7", ("rcm_every", "whole number", "2.7")),
        ("reacquire_frames: '3.5'", ("reacquire_frames", "whole number")),
        ("tof_sigma_mm: .inf", ("tof_sigma_mm", "finite", "inf")),
        ("tof_sigma_mm: -.inf", ("tof_sigma_mm", "finite")),
        ("tof_sigma_mm: .nan", ("tof_sigma_mm", "finite", "nan")),
        ("history_ms: .inf", ("history_ms", "finite")),
        ("history_ms: 1e12", ("history_ms", "at most 120000")),
        ("tof_sigma_mm: true", ("tof_sigma_mm", "expected a number", "True")),
        ("tof_sigma_mm: abc", ("tof_sigma_mm", "expected a number", "'abc'")),
        ("tof_min_mm: 500", ("tof_min_mm", "tof_max_mm", "less than")),
        ("{tof_min_mm: 100, tof_max_mm: 100}", ("tof_min_mm", "tof_max_mm")),
        ("depth_max_m: 0.01", ("depth_min_m", "depth_max_m")),
        ("gate_chi2_1: 0", ("gate_chi2_1", "> 0")),
        ("rest_tau_ms: 0", ("rest_tau_ms", "> 0")),
        ("tip_confirm_ms: 0", ("tip_confirm_ms", "> 0")),
        ("tip_confirm_chi2: -1", ("tip_confirm_chi2", ">= 0")),
        ("rest_bias: 1", ("rest_bias", "true or false")),
        ("start_depth_mm: 500", ("start_depth_mm", "depth_min_m", "20-400 mm", "500")),
        ("depth_anchor_sigma_min_mm: 0", ("depth_anchor_sigma_min_mm", "> 0")),
        ("depth_anchor_learn_spread: 1", ("depth_anchor_learn_spread", "true or false")),
    ],
)
def test_a_bad_value_is_refused_by_name(tmp_path, text, needles):
    p = tmp_path / "p.yaml"
    p.write_text(text + "\n")
    with pytest.raises(ParamsError) as e:
        load_params(p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and "\n" not in msg
    for n in needles:
        assert n in msg, msg


def test_good_values_keep_their_kind(tmp_path):
    p = tmp_path / "p.yaml"
    # YAML booleans, a whole count written 3.0, and PyYAML's strings for 1e-5-style numbers
    p.write_text("tof_map: false\nrcm_every: 3.0\naccel_bias_rw_mps2_rts: 2e-5\nhistory_ms: 2000\n")
    prm = load_params(p)
    assert prm.tof_map is False and prm.rcm_every == 3 and isinstance(prm.rcm_every, int)
    assert prm.accel_bias_rw_mps2_rts == 2e-5 and prm.history_ms == 2000.0 and isinstance(prm.history_ms, float)
    assert load_params(tmp_path / "p.yaml").to_dict() == Params.from_dict(prm.to_dict()).to_dict()
    Params()  # the defaults pass their own checks


def test_parameters_given_in_code_are_checked_too():
    with pytest.raises(ParamsError, match="tof_map: expected true or false"):
        Params(tof_map="false")
    with pytest.raises(ParamsError, match="rcm_every: expected a whole number"):
        Params(rcm_every=2.7)
    with pytest.raises(ParamsError, match="tof_sigma_mm: must be a finite number"):
        Params(tof_sigma_mm=float("inf"))


def test_sensors_empty_is_an_error_like_a_lone_comma():
    for text in ("", " ", ","):
        with pytest.raises(ParamsError, match="--sensors: empty"):
            parse_sensors(text)
    assert parse_sensors(None) == parse_sensors("all") == parse_sensors("imu,tof,vision")


def test_cli_one_line_exit_2(tmp_path, capsys):
    rec = tmp_path / "r.mcap"
    with McapWriter(rec):
        pass
    out = tmp_path / "o.mcap"
    bad = tmp_path / "p.yaml"
    cases = [
        ('tof_map: "false"\n', ["--params", str(bad)], ("p.yaml", "tof_map")),
        ("rcm_every: 2.7\n", ["--params", str(bad)], ("p.yaml", "rcm_every")),
        ("tof_min_mm: 500\n", ["--params", str(bad)], ("tof_min_mm", "tof_max_mm")),
        ("", ["--params", str(rec)], (str(rec), "not a text/YAML file")),
        ("", ["--sensors", ""], ("--sensors", "empty")),
    ]
    for text, extra, needles in cases:
        bad.write_text(text or "{}\n")
        assert main(["fusion", "run", str(rec), "--out", str(out), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "Traceback" not in err[0], err
        for n in needles:
            assert n in err[0], err[0]
    assert not out.exists()
