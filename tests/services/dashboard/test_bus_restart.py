"""The dashboard keeps its page fed across a restart of the bus: with the dashboard and the
publisher as clients of a router (a dashboard on another machine), the router goes away and
comes back on the same endpoint, and states flow again without restarting anything."""

from __future__ import annotations

import threading

from services.dashboard.app import start
from services.dashboard.auth import Tokens
from services.dashboard.config import DashboardConfig
from tests.services.dashboard.conftest import make_state
from tiplog.bus import Bus, BusConfig


def _wait_total(feed, n: int, timeout_s: float) -> bool:
    got = threading.Event()

    def check() -> None:
        if feed.state.total >= n:
            got.set()

    feed.add_listener(check)
    try:
        check()
        return got.wait(timeout_s)
    finally:
        feed.remove_listener(check)


def test_states_flow_again_after_the_router_restarts(endpoint):
    router_cfg = BusConfig(mode="router", listen=[endpoint], connect=[], prefix="restart/")
    client_cfg = BusConfig(mode="client", connect=[endpoint], listen=[], prefix="restart/")
    router = Bus(router_cfg, service="up")
    with Bus(client_cfg, service="dashboard") as dash_bus, Bus(client_cfg, service="fusion") as pub_bus:
        running = start(dash_bus, DashboardConfig(bus=client_cfg, port=0), Tokens())
        pub = pub_bus.publisher("fusion/state", reliable=False)
        stop = threading.Event()

        def publish() -> None:
            k = 0
            while not stop.wait(0.005):
                pub.put(make_state(1 + k))
                k += 1

        t = threading.Thread(target=publish, daemon=True)
        t.start()
        try:
            assert _wait_total(running.feed, 20, 20), "no state before the restart"
            router.close()
            before = running.feed.state.total
            router = Bus(router_cfg, service="up")
            assert _wait_total(running.feed, before + 50, 30), "states did not flow again after the router restarted"
        finally:
            stop.set()
            t.join()
            running.stop()
            router.close()
