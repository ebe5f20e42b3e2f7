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
