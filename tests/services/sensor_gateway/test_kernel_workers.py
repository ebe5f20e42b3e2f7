"""The gateway process with `kernel_workers_nice` or `kernel_workers_fifo`: the kernel's unbound
workers (which carry a serial port's bytes to read()) run at that nice value, or in the
real-time class at that priority, while it runs, and are put back when it stops. Real kernel
threads: root only, and only where /proc shows them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tests.conftest import ROOT
from tiplog.bus import Bus
from tiplog.priority import KernelWorker, kernel_workers

pytestmark = pytest.mark.slow

NICE = -3  # values nothing else here uses (the demo and the cart use SCHED_FIFO 1)
FIFO = 3


def _gateway_holds(listen_cfg, tmp_path, setting: str, holds, said: str) -> None:
    """Runs the gateway with `setting` until every visible worker `holds`, stops it, and checks
    that it exited cleanly having said `said`."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.sensor_gateway", "--connect", listen_cfg.listen[0],
         "--prefix", listen_cfg.prefix, "--set", f"port={tmp_path / 'no-device'}", "--set", setting],
        cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # polling the kernel's state, not timing it
            now = kernel_workers()
            if now and all(holds(w) for w in now):
                break
            time.sleep(0.1)
        assert all(holds(w) for w in now), now
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            _, err = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
    assert proc.returncode == 0, err[-2000:]
    assert said in err, err[-2000:]


@pytest.mark.skipif(os.geteuid() != 0, reason="raising kernel threads needs root")
def test_the_gateway_keeps_the_kernel_workers_raised_while_it_runs_and_puts_them_back(bus_pair_configs, tmp_path):
    if not kernel_workers():
        pytest.skip("no kernel workers visible here")
    listen_cfg, _ = bus_pair_configs
    with Bus(listen_cfg):
        # one after the other in one test: two gateways at once would each see the other's workers
        _gateway_holds(listen_cfg, tmp_path, f"kernel_workers_nice={NICE}", lambda w: w.nice <= NICE, f"to nice {NICE}")
        assert not [w for w in kernel_workers() if w.nice == NICE], kernel_workers()  # put back

        def fifo(w: KernelWorker) -> bool:
            return w.policy == os.SCHED_FIFO and w.rt_priority >= FIFO

        _gateway_holds(listen_cfg, tmp_path, f"kernel_workers_fifo={FIFO}", fifo, f"to SCHED_FIFO {FIFO}")
        assert not [w for w in kernel_workers() if w.rt_priority == FIFO], kernel_workers()
