"""The services table: services only (not `tiplog up`'s own session), and a service `tiplog up`
gave up on shown as failed with its last error line."""

from __future__ import annotations

from services.dashboard import payload
from tests.services.dashboard.conftest import VIEWER
from tiplog.bus import Bus
from tiplog.v1 import system_pb2

R = system_pb2.ServiceRunState


def test_a_failed_service_carries_its_error_and_tools_are_not_services(served, bus_pair_configs):
    feed = served.running.feed
    st = system_pb2.SupervisorStatus(event="fusion failed at start 5 times in a row (exited with 2); not restarted")
    st.services.append(
        system_pb2.ServiceRun(service="fusion", state=R.SERVICE_RUN_STATE_FAILED, restarts=4, last_exit_code=2,
                              last_error="config error: fusion.params_file: no such file")
    )  # fmt: skip
    with Bus(bus_pair_configs[1], service="up") as up:
        assert feed.health.wait_token("up", True, 10.0)
        up.publisher("system/supervisor").put(st)
        assert feed.wait_latest("system/supervisor", 10.0)
        health = served.client(VIEWER).get("/api/status").json()["health"]
    assert "up" not in health and "up" not in payload.status(feed, feed.t0_ns)["health"]
    assert health["fusion"]["run_state"] == "failed"
    assert health["fusion"]["last_error"] == "config error: fusion.params_file: no such file"
