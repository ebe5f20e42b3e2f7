"""`tiplog up`: the router plus every service as its own process, stopped cleanly."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

import pytest

from tests.conftest import ROOT, free_port
from tiplog.bus import Bus, BusConfig
from tiplog.up import DEFAULT_SERVICES

pytestmark = pytest.mark.slow


def test_up_runs_every_service_and_the_bench_reaches_the_gateway(tmp_path):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    cfg = tmp_path / "up.yaml"
    cfg.write_text(
        f"bench:\n  scenario: static\n  duration_s: 6\n  camera_tier: measurement\n  device_link: {tmp_path}/dev\n"
        f"sensor_gateway:\n  port: {tmp_path}/dev\nigtlink:\n  port: {free_port()}\ndashboard:\n  port: {free_port()}\nrecorder:\n  out_dir: {tmp_path}/rec\n  autostart: never\n  min_free_bytes: 0\n"
    )
    up = subprocess.Popen(
        [sys.executable, "-m", "tiplog.cli", "up", "--listen", ep, "-c", str(cfg)],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stderr=subprocess.PIPE,
        text=True,
    )
    alive: set[str] = set()
    all_up, gyro = threading.Event(), threading.Event()

    def on_alive(name: str, is_alive: bool) -> None:
        (alive.add if is_alive else alive.discard)(name)
        if set(DEFAULT_SERVICES) <= alive:
            all_up.set()

    try:
        with Bus(BusConfig(mode="client", connect=[ep], listen=[])) as bus:  # retries until up is listening
            bus.watch_alive(on_alive)
            bus.subscribe("device/gyro", lambda m, i: gyro.set())
            assert all_up.wait(60), f"alive: {sorted(alive)}"
            assert gyro.wait(60), "no gyro sample from the bench through the gateway"
            up.send_signal(signal.SIGINT)
            assert up.wait(15) == 0
    finally:
        if up.poll() is None:
            up.kill()


@pytest.mark.parametrize("listen", ["garbage", "tcp/999.1.1.1:7447", "tcp/127.0.0.1:99999"])
def test_a_bad_listen_endpoint_is_one_line_before_anything_starts(listen, capsys):
    from tiplog.cli import main

    with pytest.raises(SystemExit) as e:
        main(["up", "--listen", listen, "--duration", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1 and "--listen" in err[0] and listen in err[0], err
