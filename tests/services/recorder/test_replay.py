"""`tiplog replay` as a user meets it: a speed, wait or endpoint that cannot work is one line
while parsing the options, and SIGTERM stops it at once wherever it waits (between two
messages far apart at a slow speed, for a subscriber, for a router that does not answer)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from services.recorder import replay as replay_mod
from services.recorder.replay import wait_until_ns
from tests.conftest import ROOT, free_port
from tiplog.bus import Bus
from tiplog.cli import main
from tiplog.mcap_io import McapWriter
from tiplog.v1 import device_pb2

ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def test_the_wait_between_messages_ends_when_stopped():
    stop = threading.Event()
    threading.Timer(0.2, stop.set).start()
    t0 = time.monotonic()
    assert wait_until_ns(time.monotonic_ns() + 3600 * 10**9, stop) == 0
    assert time.monotonic() - t0 < 2.0


@pytest.mark.parametrize(
    ("option", "value", "needle"),
    [
        ("--speed", "nan", "finite"),
        ("--speed", "inf", "finite"),
        ("--speed", "1e-9", ">= 0.001 and <= 1000"),
        ("--speed", "0", ">= 0.001"),
        ("--wait", "-1", ">= 0"),
        ("--wait", "nan", "finite"),
        ("-e", "tcp/999.1.1.1:1", "999.1.1.1 is not an IPv4 address"),
        ("-l", "garbage", "not of the form 'tcp/HOST:PORT'"),
        ("-e", "tcp/127.0.0.1:0", "port 0 is not in 1-65535"),
    ],
)
def test_option_values_are_refused_while_parsing(tmp_path, capsys, option, value, needle):
    with pytest.raises(SystemExit) as e:
        main(["replay", str(tmp_path / "r.mcap"), option, value])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1, err
    assert option in err[0] and needle in err[0], err[0]


@pytest.fixture
def recording(tmp_path):
    """Two gyro samples 10 s apart."""
    path = tmp_path / "two.mcap"
    with McapWriter(path) as w:
        for k, t in enumerate((0, 10 * 10**9)):
            m = device_pb2.Gyro()
            m.header.stamp_ns, m.header.seq = t, k
            w.write("device/gyro", m, t)
    return path


def _sigterm_after(argv: list[str], seconds: float) -> tuple[int, float, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "tiplog.cli", *argv], cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    time.sleep(seconds)
    assert proc.poll() is None, proc.communicate()
    t0 = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    try:
        out, err = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"SIGTERM ignored: {err.decode()[-500:]}")
    return proc.returncode, time.monotonic() - t0, out.decode() + err.decode()


def test_sigterm_stops_a_slow_replay_and_a_wait_for_the_router(recording):
    nobody = f"tcp/127.0.0.1:{free_port()}"
    # the second message is due 10 s / 0.001 = 2.8 hours after the first
    slow = ["replay", str(recording), "--speed", "0.001", "--wait", "0", "-l", "tcp/127.0.0.1:0", "-e", nobody]
    rc, took, text = _sigterm_after(slow, 4.0)
    assert rc == 0 and took < 5.0 and "replayed 1 messages" in text, (rc, took, text)
    # a client whose router never answers retries until stopped
    rc, took, text = _sigterm_after(["replay", str(recording), "--max", "--mode", "client", "-e", nobody], 4.0)
    assert rc == 143 and took < 5.0, (rc, took, text)
    assert "Traceback" not in text, text


def test_the_report_counts_the_puts_late_by_over_a_millisecond(tmp_path, bus_pair_configs, monkeypatch):
    """How late each put was comes from the wait (the host's scheduler); faked at that seam,
    the report keeps the worst and counts those over 1 ms, and the puts still go out."""
    path = tmp_path / "six.mcap"
    with McapWriter(path) as w:
        for k in range(6):
            m = device_pb2.Gyro()
            m.header.stamp_ns, m.header.seq = k * 10**6, k
            w.write("device/gyro", m, k * 10**6)
    lateness = iter([0, 999_999, 1_000_000, 1_000_001, 7_500_000, 40_000])
    monkeypatch.setattr(replay_mod, "wait_until_ns", lambda due, stop=None: next(lateness))
    with Bus(bus_pair_configs[0]) as bus:
        rep = replay_mod.replay(bus, path, wait_s=0)
    assert rep.messages == 6
    assert rep.late_puts == 2 and rep.max_late_ns == 7_500_000
