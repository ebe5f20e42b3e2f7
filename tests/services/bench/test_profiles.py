"""Error profiles: precedence, recording, and that zero-sized motion sources draw nothing."""

from __future__ import annotations

import numpy as np
import pytest

from services.bench.profiles import DEFAULT_PROFILE, PROFILES
from services.bench.scenario import MOTION_DEFAULTS, Scenario, load_scenario
from services.bench.session import generate
from services.bench.simulation import simulate_session
from tiplog.config import ConfigError
from tiplog.mcap_io import read_metadata


def test_every_builtin_defaults_to_paper_and_direct_models_are_clean():
    assert DEFAULT_PROFILE == "paper"
    s = load_scenario("sweeps")
    assert s.profile == "paper"
    assert s.vision.exposure_ms == PROFILES["paper"]["vision"]["exposure_ms"] > 0
    assert s.motion.camera_rpy_deg == PROFILES["paper"]["motion"]["camera_rpy_deg"]
    bare = Scenario()
    assert bare.profile == "clean" and bare.vision.exposure_ms == 0.0 and bare.tof.surface_relief_mm == 0.0


def test_precedence_builtin_profile_file_set(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("base: teleop\nprofile: harsh\nvision:\n  exposure_ms: 5.0\n")
    s = load_scenario(f)
    assert s.profile == "harsh"
    assert s.vision.exposure_ms == 5.0  # the file's explicit field beats the profile
    assert s.tof.surface_relief_mm == PROFILES["harsh"]["tof"]["surface_relief_mm"]  # the profile beats the default
    assert s.protocol == "teleop"
    s = load_scenario(f, ["vision.exposure_ms=7", "profile=clean"])
    assert s.profile == "clean" and s.vision.exposure_ms == 7.0  # --set beats all, profile too
    assert s.tof.surface_relief_mm == 0.0 and s.motion.camera_rpy_deg == MOTION_DEFAULTS["camera_rpy_deg"]


def test_harsh_doubles_the_paper_sources():
    p, h = PROFILES["paper"], PROFILES["harsh"]
    for section in ("vision", "tof", "accel"):
        for k in ("exposure_ms", "dropout_rate_per_min", "surface_relief_mm", "vibration_mps2_per_mps"):
            if k in p[section]:
                assert h[section][k] == pytest.approx(2 * p[section][k])
    assert h["motion"] == p["motion"]  # the bench's geometry is the paper's in both


def test_unknown_profile_is_named(tmp_path):
    with pytest.raises(ConfigError, match="profile"):
        load_scenario("static", ["profile=dusty"])
    f = tmp_path / "s.yaml"
    f.write_text("profile: dusty\n")
    with pytest.raises(ConfigError, match="profile"):
        load_scenario(f)


def test_profile_recorded_in_the_session(tmp_path):
    path = tmp_path / "h.mcap"
    generate(load_scenario("teleop", ["profile=harsh"]), path, seed=1, duration_s=1.0)
    md = read_metadata(path)
    assert md["session"]["profile"] == "harsh"
    assert "profile: harsh" in md["scenario"]["yaml"]


# every motion source at its clean size, the camera as clean has it
ZEROED = {
    **{f"vision.{k}": 0.0 for k in PROFILES["paper"]["vision"] if k not in ("dropout_s", "edge_width_px")},
    "tof.integration_ms": 0.0,
    "tof.surface_relief_mm": 0.0,
    "tof.pose_corr_spread": 1.0,
    "accel.vibration_mps2_per_mps": 0.0,
    "accel.compliance_deg_per_mps2": 0.0,
    "motion.camera_rpy_deg": list(MOTION_DEFAULTS["camera_rpy_deg"]),
    "motion.camera_distance_m": MOTION_DEFAULTS["camera_distance_m"],
    "vision.metric_scale_per_px": 0.04,
}


def test_zero_sized_motion_sources_draw_nothing():
    """paper with every motion source zeroed is the clean session, draw for draw: clean keeps
    the bench's draws for a seed."""
    a = simulate_session(load_scenario("teleop", ["profile=clean"]), 3, duration_s=4.0)
    b = simulate_session(load_scenario("teleop", ZEROED), 3, duration_s=4.0)
    assert b.scenario.profile == "paper"
    for k in ("gyro", "accel", "tof", "mag"):
        np.testing.assert_array_equal(a.streams[k].values, b.streams[k].values)
    np.testing.assert_array_equal(a.vision.n_left, b.vision.n_left)
    np.testing.assert_array_equal(a.vision.junction_px, b.vision.junction_px)
    np.testing.assert_array_equal(a.vision.accepted, b.vision.accepted)
    c = simulate_session(load_scenario("teleop"), 3, duration_s=4.0)  # paper itself differs
    assert not np.array_equal(a.vision.junction_px, c.vision.junction_px)
    assert not np.array_equal(a.streams["tof"].values, c.streams["tof"].values)


def test_cli_names_a_bad_profile(tmp_path, capsys):
    from tiplog import cli

    out = tmp_path / "x.mcap"
    assert cli.main(["sim", "generate", "--scenario", "teleop", "--out", str(out), "--set", "profile=dusty"]) == 2
    err = capsys.readouterr().err
    assert "profile" in err and "dusty" in err and "Traceback" not in err
    assert not out.exists()
