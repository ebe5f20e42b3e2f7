"""`tiplog up` checks every section of the system's configuration before it starts anything: a
bad value is one line naming section and field, exit status 2, no banner, no router, no
service. A service that keeps failing at start is given up on, its error said, and `tiplog up`
exits non-zero when it stops."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys

import pytest

from tests.conftest import ROOT, free_port
from tiplog.config import ConfigError, ServiceConfig, load_config

SECTIONS = "bus, bench, sensor_gateway, vision, fusion, recorder, dashboard, igtlink, router, health, replay"
BAD = [
    (
        "fusion:\n  status_period_s: -1\n",
        "config error: fusion.status_period_s: Input should be greater than 0 (got -1)",
    ),
    ("dashboard:\n  prot: 8080\n", "config error: dashboard.prot: unknown field (got 8080)"),
    (
        "fusion:\n  status_period_s: fast\n",
        "config error: fusion.status_period_s: Input should be a valid number, unable to parse string as a number "
        "(got 'fast')",
    ),
    ("fusoin:\n  status_period_s: 1\n", "config error: fusoin: unknown section in {path} (sections: " + SECTIONS + ")"),
    (
        "dashboard:\n  port: 70000\n",
        "config error: dashboard.port: Input should be less than or equal to 65535 (got 70000)",
    ),
    (
        "bus:\n  connect: [tcp/10.0.0.300:7447]\n",
        "config error: bus.connect: Value error, endpoint 'tcp/10.0.0.300:7447': 10.0.0.300 is not an IPv4 address "
        "(four numbers 0-255) (got ['tcp/10.0.0.300:7447'])",
    ),
    (
        "recorder:\n  camera_archive: mp4\n",
        "config error: recorder.camera_archive: Input should be 'jpeg' or 'raw' (got 'mp4')",
    ),
    (  # a priority the kernel's workers would lose by
        "sensor_gateway:\n  kernel_workers_nice: 5\n",
        "config error: sensor_gateway.kernel_workers_nice: Input should be less than or equal to 0 (got 5)",
    ),
]


def _listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.mark.parametrize(("text", "line"), BAD, ids=[b[0].split(":")[0] + "." + b[0].split()[1] for b in BAD])
def test_a_bad_value_is_one_line_naming_section_and_field_and_nothing_starts(tmp_path, capsys, text, line):
    from tiplog.cli import main

    cfg = tmp_path / "system.yaml"
    cfg.write_text(text)
    port = free_port()
    rc = main(["up", "-c", str(cfg), "--listen", f"tcp/127.0.0.1:{port}", "--duration", "1"])
    out, err = capsys.readouterr()
    assert rc == 2
    assert err.strip().splitlines() == [line.format(path=cfg)]
    assert "tiplog is starting" not in out and not _listening(port)


def test_the_issue_s_bad_value_in_a_real_process_starts_nothing(tmp_path):
    cfg = tmp_path / "system.yaml"
    cfg.write_text("bench:\n  scenario: demo\nfusion:\n  status_period_s: -1\n")
    r = subprocess.run(
        [sys.executable, "-m", "tiplog.cli", "up", "-c", str(cfg), "--listen", f"tcp/127.0.0.1:{free_port()}"]
        + ["--duration", "5"],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2, r.stderr
    assert r.stderr.splitlines() == [BAD[0][1]] and r.stdout == ""


def test_a_service_s_own_unknown_field_names_its_section():
    with pytest.raises(ConfigError) as e:
        load_config(ServiceConfig, "dashboard", None, ["prot=8080"], env={})
    assert str(e.value) == "config error: dashboard.prot: unknown field (got 8080)"
    with pytest.raises(ConfigError) as e:  # the shared section is named as itself
        load_config(ServiceConfig, "dashboard", None, ["bus.mode=mesh"], env={})
    assert str(e.value).startswith("config error: bus.mode: ")


@pytest.mark.slow
def test_a_service_failing_at_start_is_given_up_on_and_up_exits_non_zero(tmp_path):
    # An address this machine does not have: the model accepts it, listening there fails.
    port = free_port()
    cfg = tmp_path / "system.yaml"
    cfg.write_text(f"igtlink:\n  host: 192.0.2.1\n  port: {port}\n  allow_remote: true\n")
    up = subprocess.Popen(
        [sys.executable, "-m", "tiplog.cli", "up", "-c", str(cfg), "--services", "igtlink"]
        + ["--listen", f"tcp/127.0.0.1:{free_port()}"],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines = []
    try:
        for line in up.stderr:
            lines.append(line.rstrip("\n"))
            if "not restarted" in line:
                break
        given_up = [ln for ln in lines if "not restarted" in ln]
        assert given_up, "\n".join(lines)
        assert "igtlink failed at start 5 times in a row (exited with 1); not restarted: " in given_up[0]
        assert f"cannot listen on 192.0.2.1:{port}" in given_up[0]
        assert given_up[0].endswith("set igtlink.host to an address of this machine"), given_up[0]
        assert sum("igtlink exited with 1" in ln for ln in lines) == 4  # restarted four times before that
        up.send_signal(signal.SIGINT)
        rest = up.stderr.read()
        assert up.wait(60) == 1
        final = rest.strip().splitlines()[-1]
        assert final.startswith("tiplog up: igtlink was given up on after 5 failed starts: cannot listen on"), rest
    finally:
        if up.poll() is None:
            up.kill()
            up.wait()
