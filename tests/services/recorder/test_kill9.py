"""kill -9 at ten seeded random moments: after `recover`, every message published more than
one second before the kill is in the file (the recorder flushes at least every 0.5 s)."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time

import pytest

from services.recorder.recover import recover
from tests.conftest import ROOT
from tests.services.recorder.conftest import StatusWatch
from tiplog.bus import Bus
from tiplog.mcap_io import read_messages
from tiplog.v1 import device_pb2, recorder_pb2

S = recorder_pb2.RecorderState


def _recorder(endpoint: str, prefix: str, out_dir) -> subprocess.Popen:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.recorder",
            "--connect",
            endpoint,
            "--prefix",
            prefix,
            "--set",
            "autostart=always",
            "--set",
            f"out_dir={out_dir}",
            "--set",
            "min_free_bytes=0",
            "--set",
            "status_period_s=0.2",
            "--set",
            "log_level=WARNING",
        ],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )


@pytest.mark.slow
def test_kill9_loses_at_most_the_last_second(bus_pair_configs, tmp_path):
    listen_cfg, _ = bus_pair_configs
    rng = random.Random(20261122)
    results = []
    with Bus(listen_cfg) as bus:
        pub = bus.publisher("device/gyro")
        for trial in range(10):
            watch = StatusWatch()
            sub = bus.subscribe("recorder/status", watch)
            proc = _recorder(listen_cfg.listen[0], listen_cfg.prefix, tmp_path / f"run{trial}")
            try:
                st = watch.wait(lambda s: s.state == S.RECORDER_STATE_RECORDING, timeout=30)
                kill_after_s = rng.uniform(1.2, 2.5)
                sent: list[int] = []  # publish time of message k, monotonic ns
                m = device_pb2.Gyro()
                t_kill = time.monotonic_ns() + int(kill_after_s * 1e9)
                k = 0
                while time.monotonic_ns() < t_kill:
                    m.header.seq = k
                    m.rate_radps.x = 1e-3 * k
                    sent.append(time.monotonic_ns())
                    pub.put(m)
                    k += 1
                    time.sleep(0.001)
                proc.send_signal(signal.SIGKILL)
                t_kill = time.monotonic_ns()
                proc.wait(10)
            finally:
                if proc.poll() is None:
                    proc.kill()
                sub.close()
            rep = recover(st.path, tmp_path / f"run{trial}.recovered.mcap")
            got = {r.message.header.seq for r in read_messages(rep.output, ["device/gyro"])}
            must = {i for i, t in enumerate(sent) if t < t_kill - 1_000_000_000}
            missing = sorted(must - got)
            newest_kept = max((sent[i] for i in got), default=0)
            results.append((trial, kill_after_s, len(sent), len(got), (t_kill - newest_kept) / 1e9))
            assert not missing, f"trial {trial}: {len(missing)} messages older than 1 s lost, first {missing[:5]}"
            assert got <= set(range(len(sent)))
    for trial, after_s, n_sent, n_kept, newest_s in results:
        print(
            f"trial {trial}: kill after {after_s:.2f} s, sent {n_sent}, kept {n_kept}, newest kept {newest_s:.3f} s before"
        )
