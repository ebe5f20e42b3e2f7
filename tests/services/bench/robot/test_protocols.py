"""Protocols: trial counts and order, stationary windows, minimum-jerk moves, envelopes, speeds."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from services.bench.robot import protocols as P
from services.bench.robot.motion import GroundTruth, MotionConfig, build_command, simulate
from tiplog.geometry import rotation_angle

CFG = MotionConfig()


@pytest.fixture(scope="module")
def commands() -> dict[str, P.Command]:
    return {name: build_command(CFG, name, seed=11) for name in P.PROTOCOLS}


def test_min_jerk_profile() -> None:
    s = P.min_jerk(1001)
    assert s[0] == 0.0 and s[-1] == 1.0 and s[500] == pytest.approx(0.5)
    ds = np.gradient(s) * 1000
    assert abs(ds[0]) < 1e-5 and abs(ds[-1]) < 1e-5
    assert ds.max() == pytest.approx(1.875, rel=1e-4)
    assert np.all(np.diff(s) >= 0)


def test_translation_trials(commands) -> None:
    cmd = commands["translation"]
    assert len(cmd.trials) == 300
    counts = Counter((t["axis"], t["magnitude"]) for t in cmd.trials)
    assert len(counts) == 30 and set(counts.values()) == {10}
    # Randomised: not grouped by condition, reproducible with the seed, changed by another seed.
    seq = [(t["axis"], t["magnitude"]) for t in cmd.trials]
    assert sum(a == b for a, b in zip(seq, seq[1:], strict=False)) < 30
    again = build_command(CFG, "translation", seed=11)
    other = build_command(CFG, "translation", seed=12)
    assert seq == [(t["axis"], t["magnitude"]) for t in again.trials]
    assert seq != [(t["axis"], t["magnitude"]) for t in other.trials]
    R_bc = CFG.R_base_camera()
    for t in cmd.trials:
        pre = cmd.p_raw_m[t["pre_start"] : t["pre_end"]]
        post = cmd.p_raw_m[t["post_start"] : t["post_end"]]
        assert (t["pre_end"] - t["pre_start"]) == (t["post_end"] - t["post_start"]) == 3000
        assert np.ptp(pre, axis=0).max() == 0.0 and np.ptp(post, axis=0).max() == 0.0
        d_cam = R_bc.T @ (post[0] - pre[0]) * 1e3
        k = "xyz".index(t["axis"])
        assert d_cam[k] == pytest.approx(t["magnitude"], abs=1e-9)
        assert np.abs(np.delete(d_cam, k)).max() < 1e-9
        # Minimum-jerk move: starts at the pre pose, ends at the post pose.
        mv = cmd.p_raw_m[t["move_start"] : t["move_end"]]
        assert np.linalg.norm(mv[-1] - post[0]) < 1e-15
        assert np.linalg.norm(mv[0] - pre[-1]) < 1e-6
        assert np.all(cmd.phase[t["pre_start"] : t["pre_end"]] == P.PRE)
        assert np.all(cmd.trial[t["move_start"] : t["move_end"]] == t["index"])
    depth0 = np.linalg.norm(cmd.p_raw_m[cmd.trials[0]["pre_start"]] - CFG.rcm_base_m)
    assert depth0 == pytest.approx(0.130, abs=1e-12)


def test_rotation_trials(commands) -> None:
    cmd = commands["rotation"]
    assert len(cmd.trials) == 180
    counts = Counter((t["axis"], t["magnitude"]) for t in cmd.trials)
    assert set(counts.values()) == {10}
    assert sorted(m for a, m in counts if a == "yaw") == [-11.0, -8.0, -5.0, 5.0, 15.0, 25.0]
    assert sorted(m for a, m in counts if a == "roll") == [-90.0, -45.0, -15.0, 15.0, 45.0, 90.0]
    seq = [(t["axis"], t["magnitude"]) for t in cmd.trials]
    assert sum(a == b for a, b in zip(seq, seq[1:], strict=False)) < 20
    for t in cmd.trials:
        for a, b in (("pre_start", "pre_end"), ("post_start", "post_end")):
            assert np.ptp(cmd.p_raw_m[t[a] : t[b]], axis=0).max() == 0.0
            assert np.ptp(cmd.roll_rad[t[a] : t[b]]) == 0.0
        depth = np.linalg.norm(cmd.p_raw_m[t["pre_start"] : t["post_end"]] - CFG.rcm_base_m, axis=1)
        np.testing.assert_allclose(depth, 0.140, atol=1e-12)


@pytest.mark.slow
def test_simulated_windows_are_stationary_and_rotations_exact() -> None:
    gt = simulate(CFG, "rotation", seed=11, duration_s=90.0)
    done = [t for t in gt.trials if t["complete"]]
    assert len(done) >= 6
    for t in done:
        for a, b in (("pre_start", "pre_end"), ("post_start", "post_end")):
            p = gt.p_tip_base_m[t[a] : t[b]]
            assert np.ptp(p, axis=0).max() < 1e-6
            R = gt.R_base_tool[t[a] : t[b]]
            assert rotation_angle(R[-1] @ R[0].T) < np.deg2rad(1e-3)
        R_rel = gt.R_base_tool[t["post_end"] - 1] @ gt.R_base_tool[t["pre_end"] - 1].T
        assert np.rad2deg(rotation_angle(R_rel)) == pytest.approx(abs(t["magnitude"]), abs=1e-3)


def test_every_protocol_respects_the_tip_speed_limit(commands) -> None:
    for name, cmd in commands.items():
        speed = np.linalg.norm(np.gradient(cmd.p_raw_m, axis=0), axis=1) * CFG.rate_hz
        assert speed.max() <= 0.050, name
        assert cmd.trial.dtype == np.int32 and cmd.phase.dtype == np.uint8
        # Every protocol starts and ends at the neutral pose, at rest.
        p0 = np.asarray(CFG.rcm_base_m) + 0.140 * CFG.R_neutral()[:, 2]
        assert np.linalg.norm(cmd.p_raw_m[0] - p0) < 1e-4, name
        assert np.linalg.norm(cmd.p_raw_m[-1] - p0) < 1e-9, name


def test_blocks_and_durations(commands) -> None:
    fit = commands["fit"]
    assert len(fit.trials) == 10
    assert sum(t["post_end"] - t["move_start"] for t in fit.trials) == 78_000
    static = commands["static"]
    holds = [t for t in static.trials if t["kind"] == "hold"]
    assert len(holds) == 20 and len({t["axis"] for t in holds}) == 4
    assert all(t["post_end"] - t["post_start"] == 30_000 for t in holds)
    soak = [t for t in static.trials if t["kind"] == "soak"]
    assert len(soak) == 1 and soak[0]["post_end"] - soak[0]["post_start"] == 300_000
    for name in P.SWEEPS:
        t = commands[name].trials[0]
        assert 102_000 <= t["move_end"] - t["move_start"] <= 137_000
    assert [t["kind"] for t in commands["sweeps"].trials] == list(P.SWEEPS)
    lat = commands["latency"]
    assert {t["axis"] for t in lat.trials} == {"depth", "tilt", "roll"}
    assert min(t["freq_hz"] for t in lat.trials if t["axis"] == "depth") == 0.1
    assert max(t["freq_hz"] for t in lat.trials if t["axis"] == "tilt") == 1.6
    assert len(commands["demo"].p_raw_m) == 100_000
    assert len(build_command(CFG, "demo", 0, duration_s=250.0).p_raw_m) == 250_000


def test_teleop_envelope(commands) -> None:
    cmd = commands["teleop"]
    assert [t["kind"] for t in cmd.trials] == ["teleop1", "teleop2", "teleop3", "teleop4"]
    r = np.asarray(CFG.rcm_base_m)
    u0 = CFG.R_neutral()[:, 2]
    for t in cmd.trials:
        assert t["move_end"] - t["move_start"] == 120_000
        d = cmd.p_raw_m[t["move_start"] : t["move_end"]] - r
        depth = np.linalg.norm(d, axis=1)
        tilt = np.degrees(np.arccos(np.clip(d @ u0 / depth, -1, 1)))
        f_depth = np.mean((depth >= 0.130) & (depth <= 0.150))
        f_tilt = np.mean(tilt <= 10.0)
        assert 0.85 <= f_depth <= 0.99, (t["kind"], f_depth)
        assert 0.93 <= f_tilt <= 0.97, (t["kind"], f_tilt)
        # Human-like: most of the motion below 1-2 Hz.
        x = d - d.mean(0)
        spec = np.abs(np.fft.rfft(x, axis=0)) ** 2
        f = np.fft.rfftfreq(len(x), 1e-3)
        assert spec[f < 1.0].sum() / spec.sum() > 0.99


def test_simulate_interface() -> None:
    gt = simulate(CFG, "fit", seed=3, duration_s=2.0)
    assert isinstance(gt, GroundTruth)
    n = 2000
    assert gt.t_ns.dtype == np.int64 and gt.t_ns[0] == 0 and np.all(np.diff(gt.t_ns) == 1_000_000)
    assert gt.q_rad.shape == (n, 7) and gt.dq_radps.shape == (n, 7)
    assert gt.R_base_tool.shape == (n, 3, 3) and gt.p_tip_base_m.shape == (n, 3)
    assert gt.rcm_base_m.shape == (3,) and gt.trial.dtype == np.int32 and gt.phase.dtype == np.uint8
    assert (GroundTruth.FREE, GroundTruth.PRE, GroundTruth.MOVE, GroundTruth.POST, GroundTruth.HOLD) == (0, 1, 2, 3, 4)
    np.testing.assert_allclose(gt.depth_m()[0], 0.140, atol=1e-9)
    assert gt.rcm_error_m()[0] < 1e-9
    assert gt.meta["protocol"] == "fit" and len(gt.trials) == 1
    assert gt.trials[0]["complete"] is False and gt.trials[0]["post_end"] == n
    with pytest.raises(ValueError, match="protocol"):
        simulate(CFG, "nope", seed=0, duration_s=1.0)
    with pytest.raises(ValueError, match="duration_s"):
        simulate(CFG, "fit", seed=0, duration_s=-1.0)
    with pytest.raises(ValueError):
        MotionConfig(unknown_field=1.0)
    with pytest.raises(ValueError):
        MotionConfig(depth_mm=500.0)
    with pytest.raises(ValueError, match="posture_seed_rad"):
        MotionConfig(posture_seed_rad=(0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0))
    with pytest.raises(ValueError, match="rcm_base_m"):
        MotionConfig(rcm_base_m=(3.0, 0.0, 0.2))
    with pytest.raises(ValueError, match="working_depth_mm"):
        MotionConfig(working_depth_mm=(150.0, 130.0))


def test_hand_eye_error_turns_the_commanded_directions() -> None:
    cfg = MotionConfig(command_camera_error_deg=(0.0, 0.74, 0.0))
    cmd = build_command(cfg, "translation", seed=0)
    R_bc = cfg.R_base_camera()
    for t in cmd.trials[:40]:
        k = "xyz".index(t["axis"])
        d = np.asarray(t["direction_base"]) / np.linalg.norm(t["direction_base"])
        ang = np.degrees(np.arccos(np.clip(abs(d @ R_bc[:, k]), -1, 1)))
        assert ang == pytest.approx(0.0 if k == 1 else 0.74, abs=1e-6)
