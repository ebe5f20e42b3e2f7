"""The RTS smoother: its forward pass is the causal filter with every late frame applied
(the runner's revised history), the backward pass moves the states, never to NaN, and the
CLI writes fusion/state_smoothed beside fusion/state."""

from __future__ import annotations

import numpy as np
import pytest

import services.fusion.offline.smoother as sm
from services.fusion.eskf.params import Params
from services.fusion.timing.runner import FusionRunner
from tests.services.fusion.sessions import bench_session, inputs
from tiplog.calibration import Calibration
from tiplog.cli import main as tiplog_main
from tiplog.mcap_io import read_messages, read_metadata


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = bench_session(tmp_path_factory, "sweeps", seed=12, duration_s=6.0)
    return path, inputs(path), Calibration.from_mcap_metadata(read_metadata(path))


def test_forward_pass_is_the_revised_causal_filter(session, monkeypatch):
    _, msgs, calib = session
    prm = Params(history_ms=60_000.0)
    runner = FusionRunner(calib, prm)
    for t, m, a in msgs:
        runner.feed(t, m, a)
    runner.finish()
    hist = runner.history()
    back = sm._backward

    def no_gain(rec, nodes, r, c):
        rec.gain = []
        return back(rec, nodes, r, c)

    monkeypatch.setattr(sm, "_backward", no_gain)
    fwd = sm.smooth(calib, prm, msgs)
    assert len(fwd) == len(hist) > 500
    np.testing.assert_array_equal([s.stamp_ns for s in fwd], [s.stamp_ns for s in hist])
    # the runner never takes in what arrives after the last state's publication: skip the tail
    k = len(hist) - 40
    np.testing.assert_allclose([s.p_tip_base_m for s in fwd[:k]], [s.p_tip_base_m for s in hist[:k]], atol=1e-12)
    monkeypatch.setattr(sm, "_backward", back)
    smoothed = sm.smooth(calib, prm, msgs)
    p_f = np.array([s.p_tip_base_m for s in fwd])
    p_s = np.array([s.p_tip_base_m for s in smoothed])
    assert np.isfinite(p_s).all()
    moved = np.linalg.norm(p_s - p_f, axis=1)
    assert moved.max() > 1e-5 and np.median(moved) < 2e-3  # it smooths, it does not wander


def test_cli_writes_the_smoothed_topic(session, tmp_path):
    path, _, _ = session
    out = tmp_path / "s.mcap"
    assert tiplog_main(["fusion", "run", str(path), "--out", str(out), "--smooth", "--quiet"]) == 0
    n = {t: sum(1 for _ in read_messages(out, [t])) for t in ("fusion/state", "fusion/state_smoothed")}
    assert n["fusion/state"] > 500 and abs(n["fusion/state_smoothed"] - n["fusion/state"]) < 50
