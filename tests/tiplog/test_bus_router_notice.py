"""A process whose router cannot be reached says so in one line naming the endpoint and how to
start one, keeps trying, and says when it got there; standalone processes find each other."""

from __future__ import annotations

import logging
import threading

import pytest

from tiplog.bus import Bus, BusConfig
from tiplog.v1 import device_pb2


class Lines(logging.Handler):
    """Records of the tiplog.bus logger; an event per wanted substring."""

    def __init__(self, *wanted: str):
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []
        self.seen = {w: threading.Event() for w in wanted}

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)
        for w, ev in self.seen.items():
            if w in record.getMessage():
                ev.set()


@pytest.fixture
def bus_log():
    logger = logging.getLogger("tiplog.bus")
    handlers: list[Lines] = []

    def attach(*wanted: str) -> Lines:
        h = Lines(*wanted)
        logger.addHandler(h)
        handlers.append(h)
        return h

    old = logger.level
    logger.setLevel(logging.DEBUG)
    yield attach
    logger.setLevel(old)
    for h in handlers:
        logger.removeHandler(h)


@pytest.mark.parametrize("mode", ["peer", "client"])
def test_no_router_is_said_once_with_the_endpoint_then_reached(mode, endpoint, bus_log):
    lines = bus_log("no router answers", "reached")
    opened: list[Bus] = []
    cfg = BusConfig(mode=mode, connect=[endpoint], listen=[] if mode == "client" else ["tcp/127.0.0.1:0"])
    t = threading.Thread(target=lambda: opened.append(Bus(cfg)))
    t.start()
    try:
        assert lines.seen["no router answers"].wait(10)
        (warning,) = [r for r in lines.records if "no router answers" in r.getMessage()]
        assert warning.levelno == logging.WARNING
        text = warning.getMessage()
        assert endpoint in text and "tiplog up" in text and f"python -m tiplog.router --listen {endpoint}" in text
        assert "\n" not in text
        with Bus(BusConfig(mode="router", listen=[endpoint], connect=[])):
            t.join(30)  # a client opens once the router answers; a peer opened at once
            assert opened, "the bus never opened"
            if mode == "peer":  # a peer opened at once and says when it reaches the router
                assert lines.seen["reached"].wait(20)
            assert len([r for r in lines.records if "no router answers" in r.getMessage()]) == 1
    finally:
        t.join(30)
        for b in opened:
            b.close()


def test_standalone_processes_find_each_other_without_a_router(endpoint):
    got = threading.Event()
    cfg = BusConfig(connect=[endpoint], standalone=True)
    with Bus(cfg) as first, Bus(cfg) as second:
        assert first.holds_endpoint == endpoint and second.holds_endpoint is None
        second.subscribe("device/gyro", lambda m, i: got.set() if m.header.seq == 7 else None)
        pub = first.publisher("device/gyro")
        m = device_pb2.Gyro()
        m.header.seq = 7
        # the subscription reaches the publisher once the two are connected: put until it arrives
        for _ in range(200):
            pub.put(m)
            if got.wait(0.05):
                break
        assert got.is_set()


def test_without_standalone_a_peer_never_listens_on_the_router_endpoint(endpoint):
    with Bus(BusConfig(connect=[endpoint])) as b:
        assert b.holds_endpoint is None


def test_a_standalone_process_with_no_router_says_so_naming_the_endpoint(endpoint, bus_log):
    lines = bus_log("no router answers")
    with Bus(BusConfig(connect=[endpoint], standalone=True)) as b:
        assert b.holds_endpoint == endpoint
        assert lines.seen["no router answers"].wait(10)
        (warning,) = [r for r in lines.records if "no router answers" in r.getMessage()]
        text = warning.getMessage()
        assert warning.levelno == logging.WARNING and "\n" not in text
        assert endpoint in text and "tiplog up" in text and f"python -m tiplog.router --listen {endpoint}" in text


def test_tiplog_replay_with_no_router_says_so_before_it_replays(tmp_path):
    import os
    import signal
    import subprocess
    import sys

    from tests.conftest import ROOT, free_port
    from tiplog.mcap_io import McapWriter

    path = tmp_path / "two.mcap"
    with McapWriter(path) as w:
        for k, t in enumerate((0, 10 * 10**9)):
            m = device_pb2.Gyro()
            m.header.stamp_ns, m.header.seq = t, k
            w.write("device/gyro", m, t)
    nobody = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "tiplog.cli", "replay", str(path), "-e", nobody],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        seen = []
        for line in proc.stderr:
            seen.append(line)
            if "no subscriber" in line:
                break
        notice = [ln for ln in seen if "no router answers" in ln]
        assert len(notice) == 1 and seen.index(notice[0]) < len(seen) - 1, seen
        assert (
            nobody in notice[0]
            and "tiplog up" in notice[0]
            and f"python -m tiplog.router --listen {nobody}" in notice[0]
        )
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)
