"""`tiplog up` refuses, in one line with exit 2, to start while another process holds its router
endpoint, the dashboard's port or the bench's device link, and names that process."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

from tests.conftest import ROOT, free_port


def _up(tmp_path, listen: str, services: str, config: str) -> subprocess.CompletedProcess:
    cfg = tmp_path / "up.yaml"
    cfg.write_text(config)
    return subprocess.run(
        [sys.executable, "-m", "tiplog.cli", "up", "--listen", listen, "-c", str(cfg), "--services", services]
        + ["--duration", "1"],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_a_held_dashboard_port_and_router_endpoint_are_named_with_their_process(tmp_path):
    with socket.socket() as router, socket.socket() as dash:
        router.bind(("127.0.0.1", 0))
        dash.bind(("127.0.0.1", 0))
        router.listen()
        dash.listen()
        listen = f"tcp/127.0.0.1:{router.getsockname()[1]}"
        dash_port = dash.getsockname()[1]
        r = _up(
            tmp_path, listen, "dashboard,igtlink", f"dashboard:\n  port: {dash_port}\nigtlink:\n  port: {dash_port}\n"
        )
    err = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(err) == 1, r.stderr
    assert f"router endpoint {listen}" in err[0] and f"dashboard port 127.0.0.1:{dash_port}" in err[0]
    assert f"OpenIGTLink port 127.0.0.1:{dash_port}" in err[0]
    assert err[0].count(f"pid {os.getpid()}") == 3, err[0]
    assert not list(tmp_path.glob("rec*")) and "Traceback" not in r.stderr


def test_a_device_link_held_by_a_live_emulator_is_named_and_a_stale_one_is_not(tmp_path):
    link = tmp_path / "device"
    master, slave = os.openpty()
    os.symlink(os.ttyname(slave), link)
    os.close(slave)
    config = f"bench:\n  device_link: {link}\n"
    try:
        r = _up(tmp_path, f"tcp/127.0.0.1:{free_port()}", "bench", config)
        assert r.returncode == 2, r.stderr
        assert f"device link {link} is held by pid {os.getpid()}" in r.stderr.strip(), r.stderr
    finally:
        os.close(master)
    # Left behind by a process that is gone: not in the way (the bench replaces it).
    assert os.path.islink(link)
    r = _up(tmp_path, f"tcp/127.0.0.1:{free_port()}", "bench", config + "  scenario: static\n  duration_s: 1\n")
    assert "cannot start" not in r.stderr, r.stderr
