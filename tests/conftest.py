"""Shared fixtures: free loopback ports and bus configurations with multicast off."""

from __future__ import annotations

import socket
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tiplog.bus import BusConfig  # noqa: E402


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def bus_pair_configs(endpoint: str) -> tuple[BusConfig, BusConfig]:
    """(listener, connector) configurations on one fresh loopback port, unique prefix."""
    prefix = f"t{free_port()}/"
    return (
        BusConfig(listen=[endpoint], connect=[], prefix=prefix),
        BusConfig(connect=[endpoint], prefix=prefix),
    )


@pytest.fixture(scope="session", autouse=True)
def _bench_pass_cache(tmp_path_factory: pytest.TempPathFactory):
    """Every bench the tests start (in this process or a child) caches its simulated passes in
    one folder of this session, not in the user's cache."""
    import os

    key = "TIPLOG_BENCH__PASS_CACHE_DIR"
    before = os.environ.get(key)
    os.environ[key] = str(tmp_path_factory.mktemp("bench-passes"))
    yield
    if before is None:
        os.environ.pop(key, None)
    else:
        os.environ[key] = before


# Tests that start a whole system (router, bench, gateway, vision, fusion, recorder, dashboard as
# processes) and assert on its rates and deadlines. Two of them at once overload a two-core
# machine, so a parallel run (`make test`: --dist loadgroup) gives them all to one worker, in turn,
# while the other workers run the rest.
WHOLE_SYSTEM = (
    "tests/system/",
    "tests/services/dashboard/test_browser.py",
    "tests/services/dashboard/test_browser_demo.py",
    "tests/services/dashboard/test_browser_real.py",
    "tests/services/dashboard/test_fuzz.py",
    "tests/tiplog/test_up.py::test_up_runs_every_service",
    "tests/tiplog/test_up_supervisor.py",
    "tests/deploy/test_compose.py::test_each_container_command",
)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.nodeid.startswith(WHOLE_SYSTEM):
            item.add_marker(pytest.mark.xdist_group("whole_system"))
