"""A running system on the simulated bench for the dashboard's end-to-end tests.

Real processes on a real Zenoh bus: a router held here, `services.bench` (measurement tier,
device bytes through a pseudo-terminal), `services.sensor_gateway` reading that terminal,
`services.recorder` and `services.dashboard` with viewer and operator tokens in its
environment. The fusion state comes from `services.fusion` when `real_fusion` is asked for
(once the live filter has landed); otherwise `StatePublisher`, a test stand-in that turns
each bench/robot sample into a FusionState and remembers every one it published.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
import yaml

from tests.conftest import ROOT, free_port
from tiplog.bus import Bus, BusConfig, SampleInfo
from tiplog.clock import now_ns
from tiplog.v1 import fusion_pb2, robot_pb2

VIEWER_TOKEN = "viewer-token-0123456789abcdef"
OPERATOR_TOKEN = "operator-token-0123456789abcdef"


class StatePublisher:
    """Publishes one FusionState per bench/robot sample: the robot's tip offset by a known
    deterministic wobble (so the error panel has something to show), depth + 0.5 mm, the
    tilt from the first shaft direction seen, a fixed ToF offset and a lock that toggles
    every 2 s. `pause()` stops publishing; `published` lists them in order."""

    def __init__(self, bus: Bus):
        self.bus = bus
        self.pub = bus.publisher("fusion/state")
        self.published: list[fusion_pb2.FusionState] = []
        self.last: fusion_pb2.FusionState | None = None
        self.running = threading.Event()
        self.running.set()
        self._u0: np.ndarray | None = None
        self._lock = threading.Lock()
        bus.subscribe("bench/robot", self._on_robot)

    def pause(self) -> fusion_pb2.FusionState | None:
        """Stop publishing; returns the last state published."""
        with self._lock:
            self.running.clear()
            return self.last

    def resume(self) -> None:
        self.running.set()

    def _on_robot(self, msg: robot_pb2.RobotState, _info: SampleInfo) -> None:
        tip = np.array([msg.tip_m.x, msg.tip_m.y, msg.tip_m.z])
        rcm = np.array([msg.rcm_m.x, msg.rcm_m.y, msg.rcm_m.z])
        u = (tip - rcm) / max(np.linalg.norm(tip - rcm), 1e-9)
        if self._u0 is None:
            self._u0 = u
        t_s = msg.header.stamp_ns / 1e9
        wobble_m = 1e-3 * np.array([np.sin(2.0 * t_s), np.cos(1.3 * t_s), 0.5 * np.sin(0.7 * t_s)])
        st = fusion_pb2.FusionState(
            depth_mm=msg.depth_mm + 0.5,
            tilt_deg=float(np.degrees(np.arccos(np.clip(u @ self._u0, -1.0, 1.0)))),
            roll_deg=12.5,
            tof_offset_mm=1.25,
            vision_locked=int(t_s / 2.0) % 2 == 0,
            attitude_sigma_deg=0.3,
        )
        # locked for 2 s, then 2 s without vision since the last frame at the window's start
        st.last_vision_stamp_ns = msg.header.stamp_ns if st.vision_locked else int(t_s / 2.0) * 2_000_000_000
        st.header.stamp_ns = msg.header.stamp_ns
        st.header.frame_id = "base"
        st.tip_m.x, st.tip_m.y, st.tip_m.z = (tip + wobble_m).tolist()
        st.shaft_direction.x, st.shaft_direction.y, st.shaft_direction.z = u.tolist()
        st.tip_sigma_mm.x = st.tip_sigma_mm.y = st.tip_sigma_mm.z = 0.8
        st.lag_ms = (now_ns() - msg.header.stamp_ns) / 1e6
        with self._lock:
            if not self.running.is_set():
                return
            self.pub.put(st)
            self.published.append(st)
            self.last = st


@dataclass
class LiveSystem:
    url: str
    router: Bus
    bus: Bus  # a client session for the test itself
    tmp: Path
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)
    fusion: StatePublisher | None = None
    logs: dict[str, Path] = field(default_factory=dict)

    def client(self, token: str | None) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=10.0)

    def log_tail(self, name: str, n: int = 20) -> str:
        p = self.logs.get(name)
        return "\n".join(p.read_text(errors="replace").splitlines()[-n:]) if p and p.exists() else ""

    def stop(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.terminate()
        for p in self.procs.values():
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
        self.bus.close()
        self.router.close()


def start_system(tmp: Path, *, real_fusion: bool = False, duration_s: float = 20.0, seed: int = 1) -> LiveSystem:
    """Start everything and wait until the dashboard has states, the reference and a recorder."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    prefix = f"d{free_port()}/"
    device = tmp / "device"
    port = free_port()
    config = {
        "bench": {
            "scenario": "demo",
            "camera_tier": "measurement",
            "device_link": str(device),
            "duration_s": duration_s,
            "seed": seed,
        },
        "sensor_gateway": {"port": str(device), "camera": {"kind": "none"}},
        "recorder": {"out_dir": str(tmp / "rec"), "autostart": "never", "min_free_bytes": 0, "status_period_s": 0.5},
        "dashboard": {"port": port},
    }
    calibration = str(_calibration(tmp, seed))
    config["dashboard"]["calibration_file"] = calibration
    config["fusion"] = {"calibration_file": calibration}
    cfg_path = tmp / "system.yaml"
    cfg_path.write_text(yaml.safe_dump(config))
    router = Bus(BusConfig(mode="router", listen=[endpoint], connect=[], prefix=prefix), service="up")
    client_bus = Bus(BusConfig(connect=[endpoint], prefix=prefix))
    system = LiveSystem(f"http://127.0.0.1:{port}", router, client_bus, tmp)
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT),
        "TIPLOG_DASHBOARD_VIEWER_TOKEN": VIEWER_TOKEN,
        "TIPLOG_DASHBOARD_OPERATOR_TOKEN": OPERATOR_TOKEN,
        "OMP_NUM_THREADS": "1",
    }
    names = ["bench", "sensor_gateway", "recorder", "dashboard"] + (["fusion"] if real_fusion else [])
    try:
        for name in names:
            log = tmp / f"{name}.log"
            system.logs[name] = log
            system.procs[name] = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    f"services.{name}",
                    "-c",
                    str(cfg_path),
                    "--connect",
                    endpoint,
                    "--prefix",
                    prefix,
                ],
                cwd=ROOT,
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=log.open("w"),
            )
        if not real_fusion:
            system.fusion = StatePublisher(client_bus)
        _wait_ready(system)
    except BaseException:
        system.stop()
        raise
    return system


def _calibration(tmp: Path, seed: int) -> Path:
    """The session's "as calibrated" constants (never the truth), as a calibration file: a
    1 s offline session of the same scenario and seed carries the same ones as the live bench."""
    from tiplog.calibration import Calibration
    from tiplog.mcap_io import read_metadata

    session = tmp / "calibration-session.mcap"
    subprocess.run(
        [sys.executable, "-m", "tiplog.cli", "sim", "generate", "--scenario", "demo", "--duration", "1"]
        + ["--seed", str(seed), "--out", str(session), "--force"],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        check=True,
        capture_output=True,
        timeout=120,
    )
    out = tmp / "calibration.yaml"
    Calibration.from_mcap_metadata(read_metadata(session)).save_yaml(out)
    return out


def _wait_ready(system: LiveSystem, timeout_s: float = 300.0) -> None:
    """Until /api/status shows fusion states, the robot and a recorder status. The bound is on a
    hang, not a speed: beside the parallel suite the bench took 69 s to start and 45 s to
    simulate its first pass."""
    deadline = time.monotonic() + timeout_s
    last = "no answer"
    with system.client(VIEWER_TOKEN) as c:
        while time.monotonic() < deadline:
            for name, p in system.procs.items():
                if p.poll() is not None:
                    raise RuntimeError(f"{name} exited with {p.returncode}:\n{system.log_tail(name)}")
            try:
                st = c.get("/api/status").json()
                state = c.get("/api/state").json()
                if state["received"] > 50 and st["robot"] and st["recorder"]:
                    return
                last = f"states {state['received']}, robot {bool(st['robot'])}, recorder {bool(st['recorder'])}"
            except (httpx.HTTPError, ValueError, KeyError) as e:
                last = repr(e)
            time.sleep(0.25)  # polling a starting system; nothing to wait on but its answers
    raise TimeoutError(f"system not ready in {timeout_s} s ({last})")


# A full-page screenshot of a page that redraws at the state rate waits for a frame to be drawn:
# under the suite's load that has taken more than Playwright's 30 s default. A hang bound.
SHOT_TIMEOUT_MS = 120_000


def signed_in(browser, system: LiveSystem, token: str, viewport=(1440, 1000)):
    """A page signed in through the login form with `token`, its trail flowing."""
    # bypass_csp: Playwright's own waits evaluate strings, which the page's policy forbids.
    ctx = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]}, bypass_csp=True)
    page = ctx.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    resp = page.goto(system.url)
    assert resp.status == 401  # the login form, nothing else
    page.fill("#token", token)
    page.click("#sign-in")
    # a hang bound: beside the parallel suite the demo's page once took over 30 s to draw 100 states
    page.wait_for_function("window.tiplog && window.tiplog.est && window.tiplog.est.n > 100", timeout=120_000)
    page.errors = errors
    return ctx, page


LOCK_HOLD_S = 1.0  # the page's: "locked" this long after the last gated vision frame


def lock_text(st: fusion_pb2.FusionState) -> str:
    """The vision pill's text for a state, as the page computes it (in doubles, as JavaScript)."""
    last, stamp = float(st.last_vision_stamp_ns), float(st.header.stamp_ns)
    if st.vision_locked or (last > 0 and stamp >= last and stamp - last < LOCK_HOLD_S * 1e9):
        return "vision: locked"
    return f"vision: no lock for {(stamp - last) / 1e9:.1f} s" if last > 0 and stamp >= last else "vision: no lock"
