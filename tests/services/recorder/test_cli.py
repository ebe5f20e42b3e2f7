"""`tiplog record ...`, `tiplog info` and `tiplog record recover` as a user runs them."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from tests.conftest import ROOT
from tests.services.recorder.conftest import StatusWatch
from tiplog.bus import Bus
from tiplog.mcap_io import read_messages, read_summary
from tiplog.v1 import device_pb2, recorder_pb2

S = recorder_pb2.RecorderState
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def tiplog(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "tiplog.cli", *args], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=timeout
    )


def test_control_commands_info_and_recover(served_recorder, bus_pair_configs, tmp_path):
    listen_cfg, _ = bus_pair_configs
    bus_args = ["--connect", listen_cfg.listen[0], "--prefix", listen_cfg.prefix]
    srv = served_recorder()
    r = tiplog("record", "start", "--session", "cli1", "operator", *bus_args)
    assert r.returncode == 0 and "ok: recording to" in r.stdout, r.stdout + r.stderr
    pub = srv.bus.publisher("device/gyro")
    for k in range(300):
        m = device_pb2.Gyro()
        m.header.seq = k
        pub.put(m)
    srv.status.wait(lambda s: "device/gyro" in s.topics and s.topics["device/gyro"].written == 300)
    assert tiplog("record", "mark", "first clip", *bus_args).returncode == 0
    r = tiplog("record", "status", "--json", *bus_args)
    st = json.loads(r.stdout)
    assert st["ok"] and st["status"]["state"] == "RECORDER_STATE_RECORDING" and st["status"]["session"] == "cli1"
    r = tiplog("record", "stop", *bus_args)
    assert r.returncode == 0 and "state IDLE" in r.stdout and "device/gyro" in r.stdout, r.stdout
    assert tiplog("record", "stop", *bus_args).returncode == 1  # not recording: says so, fails
    path = tmp_path / "rec" / "cli1_000.mcap"
    info = json.loads(tiplog("info", str(path), "--json").stdout)
    assert info["topics"]["device/gyro"]["count"] == 300 and info["gaps"] == 0
    assert info["metadata"]["event_0001"]["label"] == "first clip"
    text = tiplog("info", str(path)).stdout
    assert "device/gyro" in text and "tiplog.v1.Gyro" in text
    # A copy cut in the middle of its data: recover keeps the intact prefix and says so.
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    r = tiplog("record", "recover", str(cut), "--out", str(tmp_path / "fixed.mcap"), "--json")
    rep = json.loads(r.stdout)
    assert not rep["complete"] and rep["lost_bytes"] > 0
    assert rep["messages_by_topic"]["device/gyro"] == len(list(read_messages(tmp_path / "fixed.mcap", ["device/gyro"])))
    assert read_summary(tmp_path / "fixed.mcap").statistics.message_count == rep["messages"]
    assert (
        tiplog("record", "status", "--connect", "tcp/127.0.0.1:1", "--prefix", "nobody/", "--timeout", "0.5").returncode
        == 1
    )


def test_record_run_foreground_stops_on_sigint(bus_pair_configs, tmp_path):
    listen_cfg, _ = bus_pair_configs
    with Bus(listen_cfg) as bus:
        watch = StatusWatch()
        bus.subscribe("recorder/status", watch)
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tiplog.cli",
                "record",
                "run",
                "--start",
                "--out-dir",
                str(tmp_path / "out"),
                "--connect",
                listen_cfg.listen[0],
                "--prefix",
                listen_cfg.prefix,
                "--set",
                "min_free_bytes=0",
            ],
            cwd=ROOT,
            env=ENV,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            st = watch.wait(lambda s: s.state == S.RECORDER_STATE_RECORDING, timeout=30)
            pub = bus.publisher("device/tof")
            for k in range(20):
                m = device_pb2.Tof(range_raw_mm=float(k))
                m.header.stamp_ns = k + 1
                pub.put(m)
            watch.wait(lambda s: "device/tof" in s.topics and s.topics["device/tof"].written == 20)
            proc.send_signal(signal.SIGINT)
            assert proc.wait(10) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
    assert [r.message.range_raw_mm for r in read_messages(st.path, ["device/tof"])] == [float(k) for k in range(20)]
    assert read_summary(st.path) is not None  # finished with its summary on the way out


def test_a_bad_timeout_is_refused_while_parsing(capsys):
    from tiplog.cli import main

    for value, needle in (("-1", "> 0"), ("nan", "finite"), ("0", "> 0")):
        with pytest.raises(SystemExit) as e:
            main(["record", "status", "--timeout", value])
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and len(err) == 1 and "--timeout" in err[0] and needle in err[0], err
