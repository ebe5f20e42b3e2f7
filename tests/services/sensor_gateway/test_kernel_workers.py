"""The gateway process with `kernel_workers_nice`: the kernel's unbound workers (which carry a
serial port's bytes to read()) run at that nice value while it runs, and are put back when it
stops. Real kernel threads: root only, and only where /proc shows them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tests.conftest import ROOT
from tiplog.bus import Bus
from tiplog.priority import kernel_workers

pytestmark = pytest.mark.slow

NICE = -3  # a value nothing else here uses (the demo and the cart use -10)


@pytest.mark.skipif(os.geteuid() != 0, reason="raising kernel threads needs root")
def test_the_gateway_keeps_the_kernel_workers_raised_while_it_runs_and_puts_them_back(bus_pair_configs, tmp_path):
    if not kernel_workers():
        pytest.skip("no kernel workers visible here")
    listen_cfg, _ = bus_pair_configs
    with Bus(listen_cfg):
        proc = subprocess.Popen(
            [sys.executable, "-m", "services.sensor_gateway", "--connect", listen_cfg.listen[0],
             "--prefix", listen_cfg.prefix, "--set", f"port={tmp_path / 'no-device'}",
             "--set", f"kernel_workers_nice={NICE}"],
            cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:  # polling the kernel's state, not timing it
                now = kernel_workers()
                if now and all(n <= NICE for _, _, n in now):
                    break
                time.sleep(0.1)
            assert all(n <= NICE for _, _, n in now), now
        finally:
            proc.send_signal(signal.SIGTERM)
            try:
                _, err = proc.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                _, err = proc.communicate()
    assert proc.returncode == 0, err[-2000:]
    assert f"raised to nice {NICE}" in err
    # put back: none of the workers it raised is left at its value
    assert not [w for w in kernel_workers() if w[2] == NICE], kernel_workers()
