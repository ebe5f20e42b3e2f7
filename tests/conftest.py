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
# processes) and assert on its rates and deadlines. Three or four of them at once overload a
# two-core machine, so a parallel run (`make test`: --dist loadgroup) gives them to two workers,
# each running its share in turn, while the other workers run the rest. The shares are balanced
# by their run times (the demo's minute in the browser is the longest).
WHOLE_SYSTEM = {
    "tests/system/test_kill_each.py": "system_a",
    "tests/system/test_rogue.py": "system_a",
    "tests/services/dashboard/test_browser_demo.py": "system_a",
    "tests/services/dashboard/test_browser_real.py": "system_a",
    "tests/services/dashboard/test_fuzz.py": "system_a",
    "tests/system/": "system_b",
    "tests/services/dashboard/test_browser.py": "system_b",
    "tests/tiplog/test_up.py::test_up_runs_every_service": "system_b",
    "tests/tiplog/test_up_supervisor.py": "system_b",
    "tests/deploy/test_compose.py::test_each_container_command": "system_b",
}


def _group(nodeid: str) -> str | None:
    return next((g for prefix, g in WHOLE_SYSTEM.items() if nodeid.startswith(prefix)), None)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    # pytest-xdist (3.8) names a group in the test's id by setting item._nodeid, which pytest 9
    # no longer reads (item._id): without the name every test of a group can go to any worker,
    # and the whole systems run three and four at once. So the id is named here.
    name_in_id = getattr(config.option, "loadgroup", False) and items and hasattr(items[0], "_id")
    if name_in_id:
        from _pytest.nodeid import coerce_node_id
    for item in items:
        if group := _group(item.nodeid):
            item.add_marker(pytest.mark.xdist_group(group))
            if name_in_id:
                item._id = coerce_node_id(f"{item.nodeid}@{group}")
