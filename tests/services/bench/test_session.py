"""End-to-end: a short simulated session written to MCAP and read back."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from services.bench.scenario import load_scenario
from services.bench.sensors.calibration import BenchConstants
from services.bench.session import generate
from tiplog.mcap_io import read_messages, read_metadata

DURATION = 6.0


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = tmp_path_factory.mktemp("sim") / "teleop.mcap"
    summary = generate(load_scenario("teleop"), path, seed=7, duration_s=DURATION)
    by_topic: dict[str, list] = {}
    for r in read_messages(path):
        by_topic.setdefault(r.topic, []).append(r)
    return path, summary, by_topic


def test_topics_and_rates(session):
    path, summary, by = session
    rates = {"device/gyro": 200, "device/accel": 240, "device/tof": 100, "device/mag": 100, "vision/observation": 15}
    for topic, hz in rates.items():
        assert len(by[topic]) == pytest.approx(hz * DURATION, rel=0.03), topic
    assert len(by["camera/info"]) == 1
    # the module's hello, as the recorder writes it: the rates it was configured for
    device = read_metadata(path)["device"]
    assert json.loads(device["nominal_rates_hz"]) == {"gyro": 200, "accel": 240, "tof": 100, "mag": 100}
    assert len(by["bench/robot"]) == pytest.approx(200 * DURATION, rel=0.01)  # output.robot_rate_hz
    assert summary["messages"] == sum(len(v) for v in by.values())


def test_stamps_sequences_and_frames(session):
    _, _, by = session
    for topic in ("device/gyro", "device/accel", "device/tof", "device/mag"):
        recs = by[topic]
        stamps = np.array([r.message.header.stamp_ns for r in recs])
        assert np.array_equal(stamps, [r.log_time_ns for r in recs])  # log time = host arrival
        assert np.all(np.diff(stamps) > 0)
        assert [r.message.header.seq for r in recs] == list(range(len(recs)))
        dev = np.array([r.message.header.device_stamp_ns for r in recs])
        assert np.all(np.diff(dev) > 0) and dev[0] != stamps[0]  # the device's own clock
    assert by["device/gyro"][0].message.header.frame_id == "imu"
    g = np.array([[r.message.rate_radps.x, r.message.rate_radps.y, r.message.rate_radps.z] for r in by["device/gyro"]])
    assert np.all(np.isfinite(g)) and np.abs(g).max() < 5.0
    a = np.array([np.linalg.norm([m.x, m.y, m.z]) for m in (r.message.specific_force_mps2 for r in by["device/accel"])])
    assert np.median(a) == pytest.approx(9.81, abs=0.3)


def test_vision_observations_are_stamped_at_capture_and_logged_after_processing(session):
    _, _, by = session
    obs = by["vision/observation"]
    for r in obs:
        m = r.message
        assert r.log_time_ns == m.processed_stamp_ns > m.header.stamp_ns
        assert (m.processed_stamp_ns - m.header.stamp_ns) / 1e6 == pytest.approx(m.processing_ms, abs=1e-3)
    acc = [r.message for r in obs if r.message.accepted]
    assert 0.4 < len(acc) / len(obs) <= 1.0
    n = acc[0].n_left
    assert np.linalg.norm([n.x, n.y, n.z]) == pytest.approx(1.0)


def test_robot_truth_and_camera_info(session):
    _, _, by = session
    r0 = by["bench/robot"][0].message
    assert len(r0.q_rad) == 7 and r0.phase in ("free", "pre", "move", "post", "hold")
    assert 100.0 < r0.depth_mm < 180.0 and r0.rcm_error_mm < 1.0
    info = by["camera/info"][0].message
    assert (info.width, info.height) == (1280, 720) and info.distortion_model == "plumb_bob"


def test_metadata(session):
    path, _, _ = session
    md = read_metadata(path)
    assert md["session"]["seed"] == "7" and md["session"]["tier"] == "measurement"
    assert md["session"]["robot_rate_hz"] == "200.0"
    sc = yaml.safe_load(md["scenario"]["yaml"])
    assert sc["protocol"] == "teleop" and sc["tof"]["noise_sd_mm"] == 3.2
    assert md["calibration_truth"]["evaluation_only"] == "true"
    truth = BenchConstants.from_dict(json.loads(md["calibration_truth"]["json"]))
    cal = BenchConstants.from_dict(json.loads(md["calibration_as_calibrated"]["json"]))
    assert truth.evaluation_only and not cal.evaluation_only
    d = np.linalg.norm(truth.T_base_camera[:3, 3] - cal.T_base_camera[:3, 3])
    assert 0 < d < 0.01  # perturbed by a hand-eye error, millimetres
    assert isinstance(json.loads(md["trials"]["json"]), list)


def test_same_seed_same_file_content(tmp_path):
    sc = load_scenario("static")
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    generate(sc, a, seed=3, duration_s=2.0)
    generate(sc, b, seed=3, duration_s=2.0)
    ma = [(r.topic, r.log_time_ns, r.message.SerializeToString()) for r in read_messages(a)]
    mb = [(r.topic, r.log_time_ns, r.message.SerializeToString()) for r in read_messages(b)]
    assert ma == mb


def test_bad_tier(tmp_path):
    with pytest.raises(ValueError, match="tier"):
        generate(load_scenario("static"), tmp_path / "x.mcap", tier="bogus", duration_s=1.0)


def test_pixel_tier_writes_raw_images(tmp_path):
    pytest.importorskip("cv2")
    path = tmp_path / "px.mcap"
    generate(load_scenario("static"), path, seed=1, tier="pixel", duration_s=0.4)
    imgs = [r for r in read_messages(path, ["camera/image"])]
    assert len(imgs) == pytest.approx(0.4 * 15, abs=1)
    m = imgs[0].message
    assert (m.width, m.height, m.encoding, m.step) == (1280, 720, "rgb8", 3840) and len(m.data) == 1280 * 720 * 3
    assert not list(read_messages(path, ["vision/observation"]))
