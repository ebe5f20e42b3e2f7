"""The whole system under `tiplog up` (its own router, its supervisor) on loopback, for the
end-to-end and fault tests and the soak benchmark.

`UpRun` writes a configuration into a folder, starts `python -m tiplog.cli up` with viewer
tokens in its environment, follows `system/supervisor` on a client bus session and answers
the dashboard's API. Every service is a real process; the bench's device bytes go through a
real pseudo-terminal to the gateway.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import yaml

from tests.conftest import ROOT, free_port
from tiplog.bus import Bus, BusConfig
from tiplog.v1 import system_pb2

VIEWER_TOKEN = "viewer-token-0123456789abcdef"
OPERATOR_TOKEN = "operator-token-0123456789abcdef"
R = system_pb2.ServiceRunState


def system_config(tmp: Path, *, tier: str = "measurement", seed: int = 1, scenario: str = "demo") -> dict:
    """Configuration for every service: bench live with the emulated device on a pty, the
    gateway on it, the recorder writing from the start into tmp/rec, the dashboard on a free port."""
    device = tmp / "device"
    return {
        "bench": {"scenario": scenario, "camera_tier": tier, "device_link": str(device), "seed": seed},
        "sensor_gateway": {"port": str(device), "camera": {"kind": "none"}},
        "recorder": {"out_dir": str(tmp / "rec"), "autostart": "always", "min_free_bytes": 0, "status_period_s": 1.0},
        "dashboard": {"port": free_port()},
    }


class UpRun:
    """`tiplog up` running in a subprocess; use as a context manager (stops it on exit)."""

    def __init__(
        self,
        tmp: Path,
        services: list[str],
        config: dict | None = None,
        extra_env: dict | None = None,
        extra_args: list[str] | None = None,
    ):
        self.tmp = tmp
        self.config = config if config is not None else system_config(tmp)
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.url = f"http://127.0.0.1:{self.config['dashboard']['port']}" if "dashboard" in self.config else ""
        self.services = services
        self.statuses: list[system_pb2.SupervisorStatus] = []
        self._cv = threading.Condition()
        self.stdout_path = tmp / "up.out"
        self.stderr_path = tmp / "up.err"
        self.extra_env = extra_env or {}
        self.extra_args = extra_args or []
        self.proc: subprocess.Popen | None = None
        self.bus: Bus | None = None

    def __enter__(self) -> UpRun:
        cfg = self.tmp / "up.yaml"
        cfg.write_text(yaml.safe_dump(self.config))
        env = {
            **os.environ,
            "PYTHONPATH": str(ROOT),
            "TIPLOG_DASHBOARD_VIEWER_TOKEN": VIEWER_TOKEN,
            "TIPLOG_DASHBOARD_OPERATOR_TOKEN": OPERATOR_TOKEN,
            "OMP_NUM_THREADS": "1",
            "TORCH_NUM_THREADS": "1",
            **self.extra_env,
        }
        cmd = [sys.executable, "-m", "tiplog.cli", "up", "--listen", self.endpoint, "-c", str(cfg)]
        cmd += ["--services", ",".join(self.services), *self.extra_args]
        # its own process group, as a shell gives a foreground job: Ctrl-C reaches the group
        self.proc = subprocess.Popen(
            cmd,
            cwd=ROOT,
            env=env,
            stdout=self.stdout_path.open("w"),
            stderr=self.stderr_path.open("w"),
            start_new_session=True,
        )
        self.bus = Bus(BusConfig(mode="client", connect=[self.endpoint], listen=[]))
        self.bus.subscribe("system/supervisor", self._on_status)
        return self

    def _on_status(self, msg: system_pb2.SupervisorStatus, _info) -> None:
        with self._cv:
            self.statuses.append(msg)
            self._cv.notify_all()

    def wait_status(self, pred, timeout_s: float = 120.0) -> system_pb2.SupervisorStatus:
        """The first supervisor status (from now on or already received) for which pred holds."""
        with self._cv:
            ok = self._cv.wait_for(lambda: any(pred(s) for s in self.statuses), timeout_s)
            if not ok:
                last = self.statuses[-1] if self.statuses else "no status"
                raise TimeoutError(f"no matching supervisor status in {timeout_s} s; last: {last}\n{self.log_tail()}")
            return next(s for s in self.statuses if pred(s))

    def latest_status(self) -> system_pb2.SupervisorStatus | None:
        with self._cv:
            return self.statuses[-1] if self.statuses else None

    @staticmethod
    def run_of(status: system_pb2.SupervisorStatus, name: str):
        return next(r for r in status.services if r.service == name)

    def all_running(self, status: system_pb2.SupervisorStatus) -> bool:
        return all(self.run_of(status, n).state == R.SERVICE_RUN_STATE_RUNNING for n in self.services)

    def api(self, path: str) -> dict:
        with httpx.Client(base_url=self.url, headers={"Authorization": f"Bearer {VIEWER_TOKEN}"}, timeout=10) as c:
            r = c.get(path)
            r.raise_for_status()
            return r.json()

    def poll_api(self, path: str, pred, timeout_s: float = 120.0) -> dict:
        """GET path until pred(answer) holds (the page's own polling; no event to wait on)."""
        deadline = time.monotonic() + timeout_s
        last: object = "no answer"
        while time.monotonic() < deadline:
            self.check_alive()
            try:
                ans = self.api(path)
                if pred(ans):
                    return ans
                last = ans
            except (httpx.HTTPError, ValueError, KeyError) as e:
                last = repr(e)
            time.sleep(0.25)
        raise TimeoutError(f"GET {path}: condition not met in {timeout_s} s; last: {str(last)[:800]}")

    def check_alive(self) -> None:
        if self.proc is not None and self.proc.poll() is not None:
            raise RuntimeError(f"tiplog up exited with {self.proc.returncode}:\n{self.log_tail()}")

    def log_tail(self, n: int = 30) -> str:
        return "\n".join(self.stderr_path.read_text(errors="replace").splitlines()[-n:])

    def stop(self, timeout_s: float = 60.0) -> int:
        """Ctrl-C, as a user would (SIGINT to the whole process group, as a terminal sends it);
        returns tiplog up's exit status."""
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        if self.proc is None:
            return 0
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        return self.proc.returncode

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def recordings(self) -> list[Path]:
        return sorted((self.tmp / "rec").glob("*.mcap"))
