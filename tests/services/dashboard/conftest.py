"""A dashboard served in this process on a loopback bus, and a second session publishing to it."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from services.dashboard.app import Running, start
from services.dashboard.auth import Tokens
from services.dashboard.config import DashboardConfig
from tiplog.bus import Bus
from tiplog.v1 import fusion_pb2, robot_pb2

VIEWER = "viewer-token-0123456789abcdef"
OPERATOR = "operator-token-0123456789abcdef"


@dataclass
class Served:
    running: Running
    pub_bus: Bus

    @property
    def url(self) -> str:
        return self.running.url

    def client(self, token: str | None = None) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=10.0)

    def wait_states(self, n: int, timeout_s: float = 10.0, ring: str = "state") -> None:
        """Until the dashboard holds at least `n` rows in total in `ring` (state, reference)."""
        got = threading.Event()
        r = getattr(self.running.feed, ring)

        def check() -> None:
            if r.total >= n:
                got.set()

        self.running.feed.add_listener(check)
        try:
            check()
            assert got.wait(timeout_s), f"dashboard has {r.total} {ring} rows, expected {n}"
        finally:
            self.running.feed.remove_listener(check)


def make_state(stamp_ns: int, tip_m=(0.1, 0.2, 0.3), depth_mm: float = 140.0, tilt_deg: float = 4.0):
    st = fusion_pb2.FusionState(depth_mm=depth_mm, tilt_deg=tilt_deg, roll_deg=1.0, tof_offset_mm=0.5, lag_ms=30.0)
    st.header.stamp_ns = stamp_ns
    st.tip_m.x, st.tip_m.y, st.tip_m.z = tip_m
    return st


def make_robot(stamp_ns: int, tip_m, rcm_m, depth_mm: float = 140.0):
    r = robot_pb2.RobotState(depth_mm=depth_mm)
    r.header.stamp_ns = stamp_ns
    r.tip_m.x, r.tip_m.y, r.tip_m.z = tip_m
    r.rcm_m.x, r.rcm_m.y, r.rcm_m.z = rcm_m
    return r


CHROMIUM = "/usr/bin/chromium"


@pytest.fixture(scope="module")
def browser():
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing (make browser installs Debian's chromium)")
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox", "--disable-gpu"])
        yield b
        b.close()


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory) -> Path:
    out = Path(os.environ.get("TIPLOG_TEST_ARTIFACTS", tmp_path_factory.mktemp("artifacts")))
    out.mkdir(parents=True, exist_ok=True)
    return out


@pytest.fixture
def served(bus_pair_configs) -> Iterator[Served]:
    """Dashboard (tokens on, port 0, short recorder timeout) and a connected publisher session
    whose fusion/state the dashboard is known to receive."""
    listen_cfg, connect_cfg = bus_pair_configs
    with Bus(listen_cfg, service="dashboard") as dash_bus, Bus(connect_cfg, service="test-publisher") as pub_bus:
        cfg = DashboardConfig(bus=listen_cfg, port=0, recorder_timeout_s=0.5, trail_samples=1000)
        running = start(dash_bus, cfg, Tokens((VIEWER,), (OPERATOR,)))
        try:
            s = Served(running, pub_bus)
            probe = pub_bus.publisher("fusion/state")
            got = threading.Event()
            running.feed.add_listener(got.set)
            k = 0
            while not got.wait(0.05):  # until the two sessions see each other
                probe.put(make_state(1 + k))
                k += 1
                assert k < 400, "the dashboard never received a probe state"
            running.feed.remove_listener(got.set)
            yield s
        finally:
            running.stop()
