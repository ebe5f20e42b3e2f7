"""The live fusion service as a real process on a real Zenoh bus, fed by replaying a bench
session: its fusion/state equals the FusionRunner run offline on the inputs it consumed,
bit for bit, and so does its fusion/state_settled the settled offline run; malformed inputs are counted and the service stays up; without a calibration it
refuses to start (exit 2, one line)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from services.fusion.live.messages import to_fusion_state
from services.fusion.live.service import INPUTS
from services.fusion.timing.runner import FusionRunner
from services.recorder.replay import replay, wait_for_subscribers
from tests.conftest import ROOT
from tiplog import mcap_io, topics
from tiplog.bus import Bus
from tiplog.calibration import Calibration
from tiplog.cli import main as tiplog_main
from tiplog.v1 import device_pb2


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, Path]:
    """A 4 s sweeps session and a calibration file made from its as-calibrated metadata."""
    d = tmp_path_factory.mktemp("live")
    path = d / "sweeps.mcap"
    args = ["sim", "generate", "--scenario", "sweeps", "--seed", "7", "--duration", "4", "--out", str(path), "--quiet"]
    assert tiplog_main(args) == 0
    calib = d / "calibration.yaml"
    Calibration.from_mcap_metadata(mcap_io.read_metadata(path)).save_yaml(calib)
    return path, calib


def _start(endpoint: str, prefix: str, *sets: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "services.fusion", "--connect", endpoint, "--prefix", prefix]
    for s in ("diagnostics_hz=10", *sets):
        cmd += ["--set", s]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


class _Service:
    """The service process, with the test's bus watching its token and collecting outputs."""

    def __init__(self, listen_cfg, *sets: str):
        self.up = threading.Event()
        self.bus = Bus(listen_cfg)
        self.bus.watch_alive(lambda name, alive: alive and name == "fusion" and self.up.set())
        self.states = self.bus.subscribe("fusion/state")
        self.settled = self.bus.subscribe("fusion/state_settled")
        self.diags = self.bus.subscribe("fusion/diagnostics")
        self.tfs = self.bus.subscribe("fusion/tf")
        self.proc = _start(listen_cfg.listen[0], listen_cfg.prefix, *sets)

    def stop(self, close: bool = True) -> tuple[int, str]:
        """SIGINT and wait; `close=False` keeps the test's bus open to read what the service
        published as it stopped (`close()` later)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            rc = self.proc.wait(timeout=10)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
            if close:
                self.bus.close()
        return rc, self.proc.communicate()[1]

    def close(self) -> None:
        self.bus.close()


def _last_state_stamp(session: Path, calib: Calibration) -> int:
    """The time of the session's last gyro sample as the filter takes it (the device's clock on
    the host's, its latency off)."""
    adapter = FusionRunner(calib).adapter
    return max(adapter.measurement(r.topic, r.message).t_ns for r in mcap_io.read_messages(session, ["device/gyro"]))


def _strip(m):
    m = type(m).FromString(m.SerializeToString())
    m.lag_ms = 0.0
    m.header.seq = 0
    return m.SerializeToString()


@pytest.mark.slow
def test_live_equals_offline_on_the_inputs_it_consumed(session, bus_pair_configs, tmp_path):
    path, calib_file = session
    calib = Calibration.load_yaml(calib_file)
    log_file = tmp_path / "inputs.mcap"
    svc = _Service(bus_pair_configs[0], f"calibration_file={calib_file}", f"input_log_file={log_file}")
    stopped = False
    try:
        assert svc.up.wait(30), "fusion never declared its liveliness token"
        rep = replay(svc.bus, path, topics_=list(INPUTS), wait_s=10)
        last = _last_state_stamp(path, calib)
        live = []
        while True:  # until the state of the last gyro sample (synchronised on it, no sleep)
            got = svc.states.recv(timeout=20)
            assert got is not None, f"no state after {len(live)}; last expected at {last}"
            live.append(got[0])
            if got[0].header.stamp_ns == last:
                break
        for _ in range(100):  # the first diagnostics may predate the replay
            diag = svc.diags.recv(timeout=5)[0]
            if diag.initialised and diag.inputs > 0:
                break
        tf = svc.tfs.recv(timeout=5)[0]
        # Stopped as soon as the display stream is done, with the settled stream's last second
        # (max_age_ms) still to come: the service publishes it as it stops, so that a recording
        # ends with its inputs.
        rc, err = svc.stop(close=False)
        stopped = True
        assert rc == 0, err
        settled = []
        while True:
            got = svc.settled.recv(timeout=10)
            assert got is not None, f"no settled state after {len(settled)}; last expected at {last}"
            settled.append(got[0])
            if got[0].header.stamp_ns == last:
                break
    finally:
        if stopped:
            svc.close()
        else:
            svc.stop()
    # the service consumed exactly what was replayed, in the order it arrived
    with open(log_file, "rb") as f:
        fed = [
            (ch.topic, topics.message_type(ch.topic).FromString(m.data), m.log_time)
            for _, ch, m in make_reader(f).iter_messages(log_time_order=False)
        ]
    counts = {t: sum(1 for x in fed if x[0] == t) for t in INPUTS}
    assert counts == {t: rep.messages_by_topic[t] for t in INPUTS}
    # the offline runner on those inputs gives the same states, bit for bit
    runner = FusionRunner(calib)
    for topic, msg, arrival in fed:
        runner.feed(topic, msg, arrival)
    offline = runner.finish()
    assert len(live) == len(offline) > 100
    assert [_strip(m) for m in live] == [_strip(to_fusion_state(s)) for s in offline]
    lag = np.array([m.lag_ms for m in live])
    # held at least the output delay behind (how far behind a loaded host falls is a speed, for
    # benchmarks/live_budget.py: the parallel suite on two cores saw a median of 1.5 s)
    assert np.all(lag >= 29.0)
    # the settled stream is what `tiplog fusion run` writes from those inputs
    runner = FusionRunner(calib, output="settled")
    for topic, msg, arrival in fed:
        runner.feed(topic, msg, arrival)
    offline = runner.finish()
    assert len(settled) == len(offline) >= len(live)
    assert [_strip(m) for m in settled] == [_strip(to_fusion_state(s)) for s in offline]
    shown = {m.header.stamp_ns: m.tip_m.x for m in live}
    moved = [abs(m.tip_m.x - shown[m.header.stamp_ns]) for m in settled if m.header.stamp_ns in shown]
    assert len(moved) == len(live) and max(moved) > 1e-6  # late frames applied at their time
    lag = np.array([m.lag_ms for m in settled])
    flushed = int(np.argmax(lag < 999.0)) if np.any(lag < 999.0) else len(lag)
    assert np.all(lag[:flushed] >= 999.0)  # max_age_ms behind while running; the rest at the stop
    assert diag.mode == "full" and diag.inputs > 0 and diag.initialised
    (t,) = tf.transforms
    assert (t.parent_frame_id, t.child_frame_id) == ("base", "tool_estimate")
    assert any(
        abs(m.tip_m.x - t.translation.x) < 1e-12 and m.header.stamp_ns == t.timestamp.ToNanoseconds() for m in live
    )


@pytest.mark.slow
def test_malformed_input_is_counted_and_the_service_stays_up(session, bus_pair_configs):
    path, calib_file = session
    svc = _Service(bus_pair_configs[0], f"calibration_file={calib_file}")
    try:
        assert svc.up.wait(30)
        assert wait_for_subscribers(svc.bus, ["device/gyro"], 30)
        gyro = svc.bus.publisher("device/gyro")
        gyro.put_bytes(b"\xff\xff\xff\xff not a protobuf")
        bad = device_pb2.Gyro()
        bad.header.stamp_ns = 1
        bad.rate_radps.x = float("nan")
        gyro.put(bad)
        replay(svc.bus, path, topics_=list(INPUTS), wait_s=10)
        n = 0
        while n < 100:  # states still flow after the bad messages
            assert svc.states.recv(timeout=20) is not None
            n += 1
        while True:
            d = svc.diags.recv(timeout=10)
            assert d is not None, "no diagnostics counting the bad messages"
            r = d[0].rejected
            if r.get("device/gyro:undecodable", 0) >= 1 and r.get("input:corrupt", 0) >= 1:
                break
        assert svc.proc.poll() is None
    finally:
        rc, err = svc.stop()
    assert rc == 0, err


def test_no_calibration_exits_2_with_one_line(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for sets in ([], ["--set", f"calibration_file={tmp_path / 'missing.yaml'}"]):
        proc = subprocess.run(
            [sys.executable, "-m", "services.fusion", *sets],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert proc.returncode == 2
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "calibration_file" in lines[0], proc.stderr
