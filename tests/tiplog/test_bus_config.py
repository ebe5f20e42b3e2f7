"""Endpoints are checked where they are given (a configuration file, --set, -e/-l, `tiplog up
--listen`): zenoh itself accepts `tcp/999.1.1.1:1` and retries it for ever."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from tiplog.bus_config import BusConfig, endpoint_problem


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp/127.0.0.1:7447",
        "tcp/0.0.0.0:7447",
        "tcp/[::1]:7447",
        "tcp/router:7447",
        "tcp/sensor_gateway:7447",
        "tls/localhost:7447",
        "tcp/cart.lab.example.org:7447",
        "tcp/10.0.0.2:7447#iface=eth0",
        "udp/224.0.0.224:7446",
        "unixsock-stream//tmp/zenoh.sock",
    ],
)
def test_good_endpoints_pass(endpoint):
    assert endpoint_problem(endpoint) is None


@pytest.mark.parametrize(
    ("endpoint", "needle"),
    [
        ("garbage", "is not of the form 'tcp/HOST:PORT'"),
        ("http/1.2.3.4:80", "is not of the form"),
        ("tcp/1.2.3.4", "is not of the form"),
        ("tcp/:7447", "is not of the form"),
        ("tcp/999.1.1.1:1", "999.1.1.1 is not an IPv4 address"),
        ("tcp/1.2.3:7447", "1.2.3 is not an IPv4 address"),
        ("tcp/[zz::1]:7447", "is not an IPv6 address"),
        ("tcp/bad host:7447", "'bad host' is not a host name"),
        ("tcp/a..b:7447", "'a..b' is not a host name"),
        ("tcp/1.2.3.4:70000", "port 70000 is not in 1-65535"),
        ("tcp/1.2.3.4:0", "port 0 is not in 1-65535"),
    ],
)
def test_bad_endpoints_are_named(endpoint, needle):
    why = endpoint_problem(endpoint)
    assert why and endpoint in why and needle in why, why


def test_port_0_only_to_listen_and_the_config_checks_both_lists():
    assert endpoint_problem("tcp/127.0.0.1:0", listening=True) is None
    assert BusConfig().listen == ["tcp/127.0.0.1:0"]
    with pytest.raises(ValidationError, match="999.1.1.1 is not an IPv4 address"):
        BusConfig(connect=["tcp/999.1.1.1:1"])
    with pytest.raises(ValidationError, match="port 70000"):
        BusConfig(listen=["tcp/127.0.0.1:70000"])
