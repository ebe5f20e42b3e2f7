"""The scenario file: built-ins, paper defaults, overrides and clear errors."""

from __future__ import annotations

import pytest

from services.bench.profiles import PROFILES
from services.bench.scenario import BUILTIN, Scenario, load_scenario, scenario_dict
from tiplog.config import ConfigError


@pytest.mark.parametrize("name", sorted(BUILTIN))
def test_builtins_load(name):
    s = load_scenario(name)
    assert isinstance(s, Scenario) and s.name == name and s.protocol


def test_defaults_are_the_papers():
    s = load_scenario("static")
    assert (s.gyro.rate_hz, s.accel.rate_hz, s.tof.rate_hz, s.camera.fps) == (200, 240, 100, 15)
    assert s.instrument.shaft_radius_m == 0.00259
    assert (s.instrument.imu_proximal_m, s.instrument.tof_proximal_m) == (0.304, 0.284)
    assert s.instrument.tof_beam_off_axis_deg == 55.8 and s.instrument.tof_plane_off_neutral_deg == 13.4
    assert 6.6 <= s.gyro.latency_ms <= 6.9 and s.tof.latency_ms == 9.0 and s.tof.smoothed_latency_ms == 58.7
    assert 15.5 <= s.camera.latency_ms <= 17.3 and s.vision.processing_ms == 113.0
    assert 2.95 <= s.tof.noise_sd_mm <= 3.43 and s.tof.pose_sd_mm == 3.04
    assert s.gyro.bias_instability_dps == 0.05 and s.accel.self_recal is False
    assert (s.camera.width, s.camera.height) == (1280, 720)
    assert s.motion.neutral_tilt_deg == 28.6
    assert load_scenario("rotation").motion.neutral_tilt_deg == 30.4


def test_overrides_strings_and_dict():
    s = load_scenario("teleop", ["tof.noise_sd_mm=4.5", "motion.depth_mm=135"])
    assert s.tof.noise_sd_mm == 4.5 and s.motion.depth_mm == 135
    # the profile's camera survives a partial motion override, and so do the built-in defaults under clean
    assert s.motion.camera_distance_m == PROFILES["paper"]["motion"]["camera_distance_m"]
    assert load_scenario("teleop", ["profile=clean", "motion.depth_mm=135"]).motion.camera_distance_m == 0.085
    s = load_scenario("teleop", {"accel.self_recal": True})
    assert s.accel.self_recal


def test_unknown_field_is_named():
    with pytest.raises(ConfigError, match=r"tof\.bogus: unknown field"):
        load_scenario("static", ["tof.bogus=1"])


def test_out_of_range_is_named():
    with pytest.raises(ConfigError, match=r"gyro\.rate_hz"):
        load_scenario("static", ["gyro.rate_hz=-1"])
    with pytest.raises(ConfigError, match=r"vision\.junction_min_sin2"):
        load_scenario("static", {"vision.junction_min_sin2": 2.0})


def test_unknown_protocol_reversed_range_and_non_finite_are_named():
    with pytest.raises(ConfigError, match=r"protocol: .*unknown protocol; choose from static.*\(got 'bogus'\)"):
        load_scenario("static", ["protocol=bogus"])
    for field in ("tof.noise_factor_range", "accel.noise_factor_range", "vision.wrong_seg_deg"):
        with pytest.raises(ConfigError, match=rf"{field}: .*min <= max"):
            load_scenario("static", [f"{field}=[2,1]"])
    assert load_scenario("static", ["tof.noise_factor_range=[1,1]"]).tof.noise_factor_range == (1.0, 1.0)
    with pytest.raises(ConfigError, match=r"tof\.noise_factor_range\.0: .*finite"):
        load_scenario("static", ["tof.noise_factor_range=[.nan,1]"])
    with pytest.raises(ConfigError, match=r"instrument\.imu_lateral_m\.1: .*finite"):
        load_scenario("static", ["instrument.imu_lateral_m=[0,.inf]"])


def test_shortest_duration_holds_a_sample_of_every_stream():
    from services.bench.simulation import shortest_duration

    assert shortest_duration(load_scenario("sweeps")) == (0.013, "tof", 100.0)
    assert shortest_duration(load_scenario("sweeps", ["gyro.rate_hz=2"])) == (0.503, "gyro", 2.0)


def test_yaml_file_with_base(tmp_path):
    f = tmp_path / "mine.yaml"
    f.write_text("base: sweeps\ntof:\n  noise_sd_mm: 3.0\nvision:\n  wrong_seg_prob: 0.1\n")
    s = load_scenario(f)
    assert s.name == "mine" and s.protocol == "sweeps" and s.tof.noise_sd_mm == 3.0 and s.vision.wrong_seg_prob == 0.1
    f.write_text("camera:\n  fps: 15\n  shutter: 3\n")
    with pytest.raises(ConfigError, match=r"camera\.shutter: unknown field"):
        load_scenario(f)


def test_missing_file_and_bad_base(tmp_path):
    with pytest.raises(ConfigError, match="neither a built-in"):
        load_scenario(tmp_path / "nope.yaml")
    f = tmp_path / "b.yaml"
    f.write_text("base: nonsense\n")
    with pytest.raises(ConfigError, match="base"):
        load_scenario(f)


def test_resolved_scenario_round_trips():
    s = load_scenario("translation", ["gyro.scale_sd=0.001"])
    d = scenario_dict(s)
    assert Scenario.model_validate(d) == s
