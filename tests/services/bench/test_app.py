"""The live bench's start-up checks, on the real process: what it cannot play is one line and
exit status 2 before it joins the bus, as `tiplog sim generate` refuses it."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.conftest import ROOT, free_port


def bench(*sets: str) -> subprocess.CompletedProcess:
    argv = [sys.executable, "-m", "services.bench", "--mode", "peer", "-l", f"tcp/127.0.0.1:{free_port()}"]
    for s in ("device_link=", "camera_tier=none", *sets):
        argv += ["--set", s]
    return subprocess.run(
        argv, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize("given", ["option", "scenario file"])
def test_a_duration_without_a_sample_of_every_stream_is_refused_before_the_bus(tmp_path, given):
    # (it played on into an empty ToF stream: a traceback after the bus had opened, exit 1)
    if given == "option":
        r = bench("scenario=sweeps", "duration_s=0.001")
        what, duration = "duration_s", "0.001"
    else:
        scenario = tmp_path / "short.yaml"
        scenario.write_text("base: sweeps\nduration_s: 0.005\n")
        r = bench(f"scenario={scenario}")
        what, duration = f"the scenario's duration_s ({scenario})", "0.005"
    assert r.returncode == 2 and r.stdout == "", (r.stdout, r.stderr)
    assert r.stderr.splitlines() == [
        f"config error: {what}: {duration} s holds no sample of the tof stream at 100 Hz; give at least 0.013 s"
    ]
