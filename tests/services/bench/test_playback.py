"""The live bench's pass cache: a restarted bench plays the pass its first start simulated,
the same arrays and calibration file, without simulating; anything else it depends on changes
the key; a bad cache file or folder only costs a new simulation."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from services.bench import app, playback
from services.bench.app import BenchConfig
from services.bench.live import _device_schedule
from services.bench.scenario import load_scenario
from services.bench.simulation import simulate_session

LOG = logging.getLogger("test")


@pytest.fixture(scope="module")
def sim():
    return simulate_session(load_scenario("static"), 3, "measurement", duration_s=1.0)


def test_a_stored_pass_plays_as_simulated(sim, tmp_path):
    play = playback.Playback.from_session(sim, "calibration text")
    path = tmp_path / "x.pass"
    playback.store(path, play)
    back = playback.load(path)
    assert back is not None and back.calibration_yaml == "calibration text" and back.session is None
    for a, b in zip(_device_schedule(play), _device_schedule(back), strict=True):
        np.testing.assert_array_equal(a, b)
    for name, s in sim.streams.items():
        np.testing.assert_array_equal(back.streams[name].values, s.values)
        np.testing.assert_array_equal(back.streams[name].device_ns, s.device_ns)
    np.testing.assert_array_equal(back.gt.p_tip_base_m, sim.gt.p_tip_base_m)
    np.testing.assert_array_equal(back.camera_frames.publish_ns, sim.camera_frames.publish_ns)
    assert back.vision_payloads == sim.vision_payloads and back.clock_offset_ns == sim.clock.offset_ns
    assert back.device_rates_hz["gyro"] == sim.scenario.gyro.rate_hz and back.scenario_name == "static"
    with pytest.raises(ValueError, match="measurement tier"):
        back.render_frame(0)


def test_a_pixel_pass_renders_the_same_frames_after_the_cache(tmp_path):
    def fresh():
        return simulate_session(load_scenario("static"), 2, "pixel", duration_s=0.5)

    path = tmp_path / "p.pass"
    playback.store(path, playback.Playback.from_session(fresh()))
    back = playback.load(path)
    assert back is not None and back.session is None and back.session_pickle is not None
    np.testing.assert_array_equal(back.render_frame(1), fresh().render_frame(1))


def test_the_key_follows_everything_the_pass_depends_on(tmp_path):
    base = ("demo", [], 1, None, "measurement")
    key = playback.cache_key(*base)
    assert playback.cache_key(*base) == key
    changed = [
        ("static", [], 1, None, "measurement"),
        ("demo", ["tof.noise_mm=2"], 1, None, "measurement"),
        ("demo", [], 2, None, "measurement"),
        ("demo", [], 1, 30.0, "measurement"),
        ("demo", [], 1, None, "pixel"),
    ]
    assert len({key, *(playback.cache_key(*c) for c in changed)}) == 6
    f = tmp_path / "s.yaml"
    f.write_text("base: static\n")
    k1 = playback.cache_key(str(f), [], 1, None, "measurement")
    f.write_text("base: static\nduration_s: 5\n")
    assert playback.cache_key(str(f), [], 1, None, "measurement") != k1


def test_bad_files_and_folders_only_cost_a_simulation(sim, tmp_path, caplog):
    cut = tmp_path / "cut.pass"
    cut.write_bytes(b"\x80\x05garbage")
    assert playback.load(cut) is None and "unreadable" in caplog.text
    assert playback.load(tmp_path / "absent.pass") is None
    blocked = tmp_path / "file"
    blocked.write_text("")
    playback.store(blocked / "x.pass", playback.Playback.from_session(sim))  # its folder is a file
    assert "not written" in caplog.text
    for k in range(playback.KEEP + 2):
        playback.store(tmp_path / "keep" / f"{k}.pass", playback.Playback.from_session(sim))
    assert len(list((tmp_path / "keep").glob("*.pass"))) == playback.KEEP
    assert not list((tmp_path / "keep").glob(".*partial"))


def test_a_restart_loads_the_pass_and_writes_the_same_calibration(tmp_path, monkeypatch):
    cal = tmp_path / "calibration.yaml"
    cfg = BenchConfig(
        scenario="static", seed=4, duration_s=1.0, camera_tier="measurement",
        calibration_file=str(cal), pass_cache_dir=str(tmp_path / "cache"),
    )  # fmt: skip
    first = app._prepare(cfg, LOG)
    text = cal.read_text()
    cal.unlink()

    def no_simulation(*_a, **_k):
        raise AssertionError("simulated again")

    import services.bench.live

    monkeypatch.setattr(services.bench.live, "prepare", no_simulation)
    app.check_duration(cfg)  # checked when the pass was simulated
    again = app._prepare(cfg, LOG)
    assert cal.read_text() == text
    np.testing.assert_array_equal(again.streams["gyro"].values, first.streams["gyro"].values)
    other = cfg.model_copy(update={"seed": 5})
    assert app._cached_pass(other) != app._cached_pass(cfg)
    assert app._cached_pass(cfg.model_copy(update={"pass_cache_dir": ""})) is None
