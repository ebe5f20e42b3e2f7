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
