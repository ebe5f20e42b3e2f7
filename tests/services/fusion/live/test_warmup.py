"""The warm-up session: consistent with the calibration it is built from (the filter starts on
it and applies every stream without a rejection, rewinding for its late frames), and it loads
every compiled kernel that a real bench session then uses, in a fresh process."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from services.bench.scenario import load_scenario
from services.bench.simulation import as_calibrated_constants
from services.fusion.eskf.params import Params
from services.fusion.live.warmup import synthetic_inputs, tangent_normals, warm_up
from tests.conftest import ROOT
from tests.services.fusion.sessions import bench_session
from tiplog.calibration import Calibration


def _bench_calibration(scenario: str, seed: int) -> Calibration:
    return Calibration.from_dict(as_calibrated_constants(load_scenario(scenario), seed).to_dict())


def test_tangent_planes_touch_the_shaft_and_contain_the_camera_centre():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.normal(size=3) * 0.1 + [0.0, 0.0, 0.2]
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        r = 0.0025
        for n in tangent_normals(a, u, r):
            assert abs(np.linalg.norm(n) - 1.0) < 1e-12
            assert abs(n @ u) < 1e-12  # parallel to the axis
            for s in (-0.1, 0.0, 0.3):
                assert abs(n @ (a + s * u) - r) < 1e-12  # every axis point at the radius
        n_l, n_r = tangent_normals(a, u, r)
        assert np.linalg.norm(n_l - n_r) > 1e-3  # two planes, not one
    with pytest.raises(ValueError, match="inside the shaft"):
        tangent_normals(np.array([0.001, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), 0.0025)


@pytest.mark.parametrize(("scenario", "seed"), [("teleop", 0), ("sweeps", 5), ("static", 9)])
def test_the_filter_starts_on_it_and_applies_every_stream(scenario, seed):
    diag = warm_up(_bench_calibration(scenario, seed))
    assert diag["initialised"] and diag["resets"] == 0
    for stream in ("gravity", "rcm", "tof", "vision_axis", "vision_tip"):
        assert diag["updates"].get(stream, 0) > 0, (stream, diag["updates"])
    assert diag["rejected"] == {}, diag["rejected"]
    assert diag["rewinds"] > 0  # its frames arrive after later gyro samples, as live


def test_inputs_follow_the_calibrated_latencies_and_arrive_in_order():
    calib = _bench_calibration("teleop", 0)
    msgs = synthetic_inputs(calib, Params())
    arrivals = [a for _, _, a in msgs]
    assert arrivals == sorted(arrivals)
    topics = {t for t, _, _ in msgs}
    assert topics == {"device/gyro", "device/accel", "device/tof", "vision/observation"}
    gyro0 = next(m for t, m, _ in msgs if t == "device/gyro")
    cam0 = next(m for t, m, _ in msgs if t == "vision/observation")
    # both streams start at the same capture time: their stamps differ by the latencies
    expect = calib.latency_ns("camera") - calib.latency_ns("gyro")
    assert cam0.header.stamp_ns - gyro0.header.stamp_ns == expect
    assert any(not m.junction_visible for t, m, _ in msgs if t == "vision/observation")


def test_a_real_session_needs_no_kernel_the_warm_up_did_not_load(tmp_path_factory):
    """In a fresh process (compiled code is per process): nothing loaded at first, the warm-up
    loads some kernels, and a 9 s bench session afterwards adds none."""
    pytest.importorskip("numba")
    path = bench_session(tmp_path_factory, "sweeps", seed=12, duration_s=9.0)
    script = """
import importlib, json, pkgutil, sys
from numba.core.registry import CPUDispatcher
from services.fusion.eskf import kernels, models
from services.fusion.timing.runner import FusionRunner
from services.fusion.live.warmup import warm_up
from tiplog.calibration import Calibration
from tiplog.mcap_io import read_messages, read_metadata

# every kernel of the filter, each under the module that defines it
mods = [importlib.import_module(f"{p.__name__}.{m.name}") for p in (kernels, models) for m in pkgutil.iter_modules(p.__path__)]
ALL = {f"{m.__name__}.{n}": d for m in mods for n, d in vars(m).items()
       if isinstance(d, CPUDispatcher) and d.py_func.__module__ == m.__name__}

def loaded():
    return {n: len(d.signatures) for n, d in ALL.items()}

path = sys.argv[1]
calib = Calibration.from_mcap_metadata(read_metadata(path))
before = loaded()
warm_up(calib)
warmed = loaded()
runner = FusionRunner(calib, output="both")
states = 0
for r in read_messages(path, ("device/gyro", "device/accel", "device/tof", "vision/observation")):
    runner.feed(r.topic, r.message, r.log_time_ns)
    states += len(runner.advance(r.log_time_ns))
    runner.take_settled()
print(json.dumps({"before": before, "warmed": warmed, "after": loaded(), "states": states}))
"""
    out = subprocess.run(
        [sys.executable, "-c", script, str(path)], cwd=ROOT, capture_output=True, text=True, timeout=240, check=True
    )
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["states"] > 1000  # the session ran
    assert not any(r["before"].values()), r["before"]
    assert len(r["before"]) >= 25, sorted(r["before"])  # the kernels of every module were found
    assert sum(v > 0 for v in r["warmed"].values()) >= 5, r["warmed"]
    assert r["after"] == r["warmed"], {k: (r["warmed"][k], v) for k, v in r["after"].items() if v != r["warmed"][k]}


def test_the_command_fills_the_cache_or_says_why_not(tmp_path):
    bad = tmp_path / "cal.yaml"
    bad.write_text("rcm_base_m: [0, 0]\n")
    out = subprocess.run(
        [sys.executable, "-m", "services.fusion.live.warmup", str(bad)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and str(bad) in out.stderr and "Traceback" not in out.stderr
    ok = subprocess.run(
        [sys.executable, "-m", "services.fusion.live.warmup"], cwd=ROOT, capture_output=True, text=True, timeout=240
    )
    assert ok.returncode == 0, ok.stderr
    assert "fusion kernels ready in" in ok.stdout or "fusion kernels compiled in" in ok.stdout
    assert "the smoother's in" in ok.stdout and "attitude kernels ready in" in ok.stdout, ok.stdout
    # `make` runs the two halves as two processes, side by side
    attitude = subprocess.run(
        [sys.executable, "-m", "services.fusion.live.warmup", "--only", "attitude"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert attitude.returncode == 0, attitude.stderr
    assert "attitude kernels ready in" in attitude.stdout and "fusion kernels" not in attitude.stdout


def test_a_start_with_no_compiled_cache_says_so_first(tmp_path):
    """An empty cache folder (a fresh install): the service's line says that it compiles, where
    the cache is and how long it takes; the cache in use here (filled by the warm-up) says nothing."""
    pytest.importorskip("numba")
    script = "from services.fusion.live.warmup import kernel_cache, cold_start_line; print(kernel_cache()[0]); print(cold_start_line())"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    cached, line = out.stdout.strip().splitlines()
    assert cached == "False"
    assert line.startswith("compiling the filter's kernels") and str(tmp_path) in line and "s on two" in line
    from services.fusion.live.warmup import cold_start_line, kernel_cache, warm_up

    warm_up(_bench_calibration("teleop", 0))
    assert kernel_cache()[0] is True and cold_start_line() is None


def test_a_calibration_it_cannot_use_only_costs_the_warm_up(caplog):
    """The live service still starts (the kernels then load with the first samples)."""
    from services.fusion.live.service import warm_kernels

    d = _bench_calibration("teleop", 0).to_dict()
    d["shaft_radius_m"] = 5.0  # the camera inside the shaft: no frame to build
    with caplog.at_level("INFO", logger="tiplog.fusion"):
        warm_kernels(Calibration.from_dict(d), Params(), frozenset({"imu", "tof", "vision"}))
    assert "warm-up skipped (no pose of the shaft" in caplog.text
    caplog.clear()
    with caplog.at_level("INFO", logger="tiplog.fusion"):
        warm_kernels(_bench_calibration("teleop", 0), Params(), frozenset({"imu", "tof", "vision"}))
    assert "filter kernels ready in" in caplog.text


def test_a_spare_waits_for_the_running_fusions_cache_instead_of_compiling_beside_it(monkeypatch):
    from services.fusion.live import app

    answers = iter([False, False, True])
    monkeypatch.setattr(app, "kernel_cache", lambda: (next(answers), "cache"))
    warmed = []
    monkeypatch.setattr(app, "warm_kernels", lambda *a: warmed.append(a))
    monkeypatch.setattr(app, "_inputs", lambda cfg: ("calibration", "params", "sensors"))
    monkeypatch.setattr(app.time, "sleep", lambda s: None)  # the poll's period
    app.prepare(None)
    assert warmed == [("calibration", "params", "sensors")] and next(answers, "done") == "done"
    monkeypatch.setattr(app, "kernel_cache", lambda: (None, ""))  # no numba: nothing to wait for
    app.prepare(None)
    assert len(warmed) == 2
    app._prepared.clear()
