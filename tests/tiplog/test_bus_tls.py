"""Two bus sessions over TLS on loopback, with certificates made by the documented command
(scripts/make-certs.sh); a session that does not trust the CA does not get in."""

from __future__ import annotations

import shutil
import subprocess
import threading

import pytest

from tests.conftest import ROOT, free_port
from tiplog.bus import Bus, BusConfig
from tiplog.v1 import device_pb2

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")


def make_certs(out, host="localhost", ip="127.0.0.1"):
    subprocess.run(
        ["bash", str(ROOT / "scripts" / "make-certs.sh"), str(out), host, ip], check=True, capture_output=True
    )
    return out / "ca.pem", out / "router.pem", out / "router.key"


def test_router_and_client_over_tls(tmp_path):
    ca, cert, key = make_certs(tmp_path / "certs")
    ep = f"tls/localhost:{free_port()}"
    router = BusConfig(
        mode="router", listen=[ep], connect=[], tls_root_ca=str(ca), tls_certificate=str(cert), tls_private_key=str(key)
    )
    client = BusConfig(mode="client", connect=[ep], listen=[], tls_root_ca=str(ca), open_timeout_s=20)
    got = threading.Event()
    with Bus(router) as r, Bus(client) as c:
        r.subscribe("device/gyro", lambda m, i: got.set() if m.header.seq == 42 else None)
        pub = c.publisher("device/gyro")
        m = device_pb2.Gyro()
        m.header.seq = 42
        for _ in range(100):  # until the subscription has reached the client
            pub.put(m)
            if got.wait(0.05):
                break
        assert got.is_set()


def test_a_client_that_does_not_trust_the_ca_is_refused(tmp_path):
    ca, cert, key = make_certs(tmp_path / "cart")
    other_ca, _, _ = make_certs(tmp_path / "other")
    ep = f"tls/localhost:{free_port()}"
    router = BusConfig(
        mode="router", listen=[ep], connect=[], tls_root_ca=str(ca), tls_certificate=str(cert), tls_private_key=str(key)
    )
    stranger = BusConfig(mode="client", connect=[ep], listen=[], tls_root_ca=str(other_ca), open_timeout_s=1.0)
    with Bus(router), pytest.raises(ConnectionError, match="no router answered"):
        Bus(stranger)


def test_tls_settings_are_checked_when_the_service_starts(tmp_path):
    with pytest.raises(ValueError, match="needs tls_root_ca"):
        BusConfig(mode="client", connect=["tls/localhost:7447"], listen=[])
    with pytest.raises(ValueError, match="no such file"):
        BusConfig(tls_root_ca=str(tmp_path / "missing.pem"))
