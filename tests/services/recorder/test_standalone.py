"""`tiplog record run` and `tiplog replay` in two terminals, with nothing else started (no
`tiplog up`, no router): the first one holds the endpoint, the other joins it, and the
recording holds every message replayed, whichever started first."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from tests.conftest import ROOT
from tests.services.recorder.test_cli import ENV
from tiplog.mcap_io import McapWriter, read_messages
from tiplog.v1 import device_pb2, recorder_pb2

S = recorder_pb2.RecorderState
N = 300


def _recording(path) -> None:
    with McapWriter(path) as w:
        for k in range(N):
            m = device_pb2.Gyro()
            m.header.seq = k
            m.rate_radps.x = 1e-3 * k
            w.write("device/gyro", m, log_time_ns=1_000_000_000 + 5_000_000 * k)


@pytest.mark.slow
@pytest.mark.parametrize("first", ["record", "replay"])
def test_record_and_replay_alone_find_each_other(first, endpoint, tmp_path):
    src = tmp_path / "in.mcap"
    _recording(src)
    out = tmp_path / "out"
    record = [sys.executable, "-m", "tiplog.cli", "record", "run", "--start", "--out-dir", str(out)]
    record += ["--connect", endpoint, "--set", "min_free_bytes=0", "--set", "log_level=DEBUG"]
    replay = [
        sys.executable,
        "-m",
        "tiplog.cli",
        "--log-level",
        "DEBUG",
        "replay",
        str(src),
        "--max",
        "--wait",
        "60",
        "--connect",
        endpoint,
    ]
    cmds = {"record": record, "replay": replay}
    procs: dict[str, subprocess.Popen] = {}
    try:
        for name in (first, "replay" if first == "record" else "record"):
            procs[name] = subprocess.Popen(
                cmds[name], cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
        # replay starts once the recorder's subscription matches its topics, and ends when all is sent
        out_text, err_text = procs["replay"].communicate(timeout=90)
        assert procs["replay"].returncode == 0, err_text
        assert f"replayed {N} messages" in out_text
        procs["record"].send_signal(signal.SIGINT)
        _, rec_err = procs["record"].communicate(timeout=15)
        assert procs["record"].returncode == 0, rec_err
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
    # whichever bound first holds the endpoint (not always the one started first), never both
    held = [f"no router at {endpoint}: listening there" in log for log in (rec_err, err_text)]
    assert sorted(held) == [False, True]
    (path,) = out.glob("*.mcap")
    got = [r.message.header.seq for r in read_messages(path, ["device/gyro"])]
    assert got == list(range(N))
