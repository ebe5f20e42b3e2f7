from __future__ import annotations

import os
import random
import subprocess
import sys
import threading

import pytest
import zenoh

from tests.conftest import ROOT
from tiplog.bus import Bus, BusConfig, decode_attachment, encode_attachment
from tiplog.v1 import device_pb2


def test_two_processes_1000_typed_messages_in_order(bus_pair_configs):
    listen_cfg, connect_cfg = bus_pair_configs
    n = 1000
    got: list[tuple[int, int, float]] = []
    all_in = threading.Event()

    def on_gyro(msg: device_pb2.Gyro, info) -> None:
        got.append((msg.header.seq, info.seq, msg.rate_radps.x))
        if len(got) == n:
            all_in.set()

    with Bus(listen_cfg) as bus:
        sub = bus.subscribe("device/gyro", on_gyro)
        child = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tests.helpers.publish_gyros",
                "--connect",
                listen_cfg.listen[0],
                "--prefix",
                listen_cfg.prefix,
                "-n",
                str(n),
            ],
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
        )
        try:
            # The token is declared after the subscriber, on the same session: once the
            # publisher sees it, it has seen the subscriber too.
            ready_token = bus.session.liveliness().declare_token(bus.key("alive/test-subscriber"))
            assert all_in.wait(30), f"only {len(got)} of {n} arrived"
            done_token = bus.session.liveliness().declare_token(bus.key("alive/test-done"))
            assert child.wait(30) == 0
            done_token.undeclare()
            ready_token.undeclare()
        finally:
            if child.poll() is None:
                child.kill()
        assert [g[0] for g in got] == list(range(n))
        assert [g[1] for g in got] == list(range(n)), "bus sequence numbers out of order"
        assert got[-1][2] == pytest.approx((n - 1) * 1e-3)
        assert sub.decode_errors == 0


def test_random_payloads_are_counted_not_raised(bus_pair_configs):
    listen_cfg, connect_cfg = bus_pair_configs
    rng = random.Random(1234)
    valid = threading.Event()
    received: list[int] = []

    def on_gyro(msg, info) -> None:
        received.append(msg.header.seq)
        valid.set()

    with Bus(listen_cfg) as sub_bus, Bus(connect_cfg) as pub_bus:
        sub = sub_bus.subscribe("device/gyro", on_gyro)
        # A foreign publisher on the same key: plain zenoh puts of random bytes.
        raw = pub_bus.session.declare_publisher(
            pub_bus.key("device/gyro"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        typed = pub_bus.publisher("device/gyro")
        matched = threading.Event()
        listener = raw.declare_matching_listener(lambda status: status.matching and matched.set())
        assert matched.wait(10) or raw.matching_status
        for _ in range(1000):
            raw.put(bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 200))))
        m = device_pb2.Gyro()
        m.header.seq = 424242
        typed.put(m)
        assert valid.wait(10), "the valid message after the garbage never arrived"
        assert received == [424242]
        assert sub.decode_errors == 1000
        listener.undeclare()
        raw.undeclare()


def test_garbage_with_a_tiplog_attachment_is_counted(bus_pair_configs):
    listen_cfg, connect_cfg = bus_pair_configs
    got = threading.Event()
    with Bus(listen_cfg) as a, Bus(connect_cfg) as b:
        sub = a.subscribe("device/gyro", lambda m, i: got.set())
        raw = b.session.declare_publisher(b.key("device/gyro"), congestion_control=zenoh.CongestionControl.BLOCK)
        matched = threading.Event()
        lst = raw.declare_matching_listener(lambda s: s.matching and matched.set())
        assert matched.wait(10) or raw.matching_status
        att = encode_attachment(0, 0, 7, "tiplog.v1.Gyro")
        raw.put(b"\x0a\xff\xff\xff\xff\x0f", attachment=att)  # length-delimited header past the end
        raw.put(device_pb2.Accel().SerializeToString(), attachment=encode_attachment(1, 0, 7, "tiplog.v1.Accel"))
        good = device_pb2.Gyro()
        good.header.seq = 5
        raw.put(good.SerializeToString(), attachment=encode_attachment(2, 0, 7, "tiplog.v1.Gyro"))
        assert got.wait(10)
        assert sub.decode_errors == 2
        assert sub.received == 1
        lst.undeclare()
        raw.undeclare()


def test_attachment_round_trip():
    raw = encode_attachment(2**40 + 3, -5, 0xDEADBEEF, "tiplog.v1.Tof")
    assert decode_attachment(raw) == (2**40 + 3, -5, 0xDEADBEEF, "tiplog.v1.Tof")
    assert decode_attachment(None) == (0, 0, 0, "")
    assert decode_attachment(b"\x01\x02") == (0, 0, 0, "")


def test_publisher_rejects_wrong_type(bus_pair_configs):
    with Bus(bus_pair_configs[0]) as bus:
        pub = bus.publisher("device/gyro")
        with pytest.raises(TypeError, match="tiplog.v1.Gyro"):
            pub.put(device_pb2.Accel())


def test_liveliness_lists_services(bus_pair_configs):
    listen_cfg, connect_cfg = bus_pair_configs
    seen = threading.Event()
    with Bus(listen_cfg, service="fusion") as a:
        a.watch_alive(lambda name, alive: alive and name == "recorder" and seen.set())
        with Bus(connect_cfg, service="recorder") as b:
            assert seen.wait(10)
            assert {"fusion", "recorder"} <= b.alive(2.0)


def test_bus_config_rejects_bad_values():
    with pytest.raises(ValueError, match="prefix"):
        BusConfig(prefix="tiplog")
    with pytest.raises(ValueError, match="endpoint"):
        BusConfig(connect=["127.0.0.1:7447"])


def test_client_waits_for_a_router_that_comes_later(endpoint):
    opened = threading.Event()
    holder: list[Bus] = []

    def open_client() -> None:
        holder.append(Bus(BusConfig(mode="client", connect=[endpoint], listen=[], open_timeout_s=30)))
        opened.set()

    t = threading.Thread(target=open_client)
    t.start()
    assert not opened.wait(0.3)  # no router yet: still waiting, not failed
    with Bus(BusConfig(mode="router", listen=[endpoint], connect=[])):
        assert opened.wait(20)
        holder[0].close()
    t.join()


def test_client_without_router_fails_with_a_clear_error(endpoint):
    stop = threading.Event()
    with pytest.raises(ConnectionError, match=r"no router answered at tcp/127\.0\.0\.1:\d+ within 0\.3 s"):
        Bus(BusConfig(mode="client", connect=[endpoint], listen=[], open_timeout_s=0.3), stop=stop)
