"""Tokens: where they come from, what each grants, and the refusal to serve a non-loopback
address without them."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import httpx
import pytest

from services.dashboard.app import start
from services.dashboard.auth import ENV_OPERATOR, ENV_VIEWER, Role, Tokens, bearer, check_binding, load_tokens
from services.dashboard.config import DashboardConfig, host_is_loopback
from tests.conftest import ROOT
from tiplog.bus import Bus
from tiplog.userio import UserError

V = "viewer-token-aaaaaaaaaaaa"
OP = "operator-token-bbbbbbbbbbbb"


def test_roles_from_environment():
    tokens = load_tokens(None, env={ENV_VIEWER: V, ENV_OPERATOR: f"{OP}, {OP}2"})
    assert tokens.role_of(V) == Role.VIEWER
    assert tokens.role_of(OP) == Role.OPERATOR and tokens.role_of(OP + "2") == Role.OPERATOR
    assert tokens.role_of(V[:-1]) == Role.NONE
    assert tokens.role_of("") == Role.NONE and tokens.role_of(None) == Role.NONE


def test_without_tokens_every_local_client_is_operator():
    tokens = load_tokens(None, env={})
    assert not tokens.enabled
    assert tokens.role_of(None) == Role.OPERATOR


def test_token_file(tmp_path):
    f = tmp_path / "tokens.yaml"
    f.write_text(f"viewer: [{V}]\noperator: {OP}\n")
    f.chmod(0o600)
    tokens = load_tokens(str(f), env={})
    assert tokens == Tokens((V,), (OP,))


@pytest.mark.parametrize(
    "text, message",
    [
        ("viewer: short\n", "shorter than 16"),
        ("admin: xxxxxxxxxxxxxxxxxxxxxx\n", "expected a mapping"),
        (f"viewer: {V}\noperator: {V}\n", "both as viewer and as operator"),
        ("viewer: [1, 2]\n", "list of token strings"),
        ("viewer: [unclosed\n", "not a valid YAML"),
    ],
)
def test_bad_token_file_names_the_problem(tmp_path, text, message):
    f = tmp_path / "tokens.yaml"
    f.write_text(text)
    with pytest.raises(UserError, match=message):
        load_tokens(str(f), env={})


def test_missing_token_file(tmp_path):
    with pytest.raises(UserError, match="no such token file"):
        load_tokens(str(tmp_path / "nope.yaml"), env={})


def test_binding_rules():
    assert host_is_loopback("127.0.0.1") and host_is_loopback("::1") and host_is_loopback("localhost")
    assert not host_is_loopback("0.0.0.0") and not host_is_loopback("10.0.0.5")
    check_binding(True, "127.0.0.1", Tokens())  # loopback: fine without tokens
    with pytest.raises(UserError, match="viewer or operator token"):
        check_binding(False, "0.0.0.0", Tokens())
    with pytest.raises(UserError, match="operator token"):
        check_binding(False, "0.0.0.0", Tokens(viewer=(V,)))
    check_binding(False, "0.0.0.0", Tokens((V,), (OP,)))


def test_bearer_header():
    assert bearer(f"Bearer {V}") == V and bearer(f"bearer  {V} ") == V
    assert bearer("Basic abc") is None and bearer(None) is None and bearer("Bearer ") is None


def test_tokens_are_not_configuration_fields():
    # --set and the YAML file cannot carry a token: the field does not exist.
    assert not {"viewer_token", "operator_token", "tokens"} & set(DashboardConfig.model_fields)


def test_service_refuses_a_public_address_without_tokens(bus_pair_configs):
    listen_cfg, _ = bus_pair_configs
    env = {k: v for k, v in os.environ.items() if k not in (ENV_VIEWER, ENV_OPERATOR)}
    with Bus(listen_cfg):
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "services.dashboard",
                "--connect",
                listen_cfg.listen[0],
                "--prefix",
                listen_cfg.prefix,
            ]
            + ["--set", "host=0.0.0.0", "--set", "port=0"],
            cwd=ROOT,
            env={**env, "PYTHONPATH": str(ROOT)},
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert proc.returncode == 2, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if " ERROR " in ln]
    assert len(errors) == 1 and "0.0.0.0 is not loopback" in errors[0], proc.stderr
    assert "Traceback" not in proc.stderr


def _self_signed(tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl is needed to make a test certificate")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=127.0.0.1"]
        + ["-keyout", str(key), "-out", str(cert)],
        check=True,
        capture_output=True,
        timeout=60,
    )
    return cert, key


def test_https_with_a_certificate(bus_pair_configs, tmp_path):
    cert, key = _self_signed(tmp_path)
    listen_cfg, _ = bus_pair_configs
    with Bus(listen_cfg, service="dashboard") as bus:
        cfg = DashboardConfig(bus=listen_cfg, port=0, tls_certfile=str(cert), tls_keyfile=str(key))
        running = start(bus, cfg, Tokens((V,), (OP,)))
        try:
            assert running.url.startswith("https://")
            with httpx.Client(base_url=running.url, verify=False) as c:
                assert c.get("/api/state").status_code == 401
                r = c.post(
                    "/login", content=f"token={OP}", headers={"Content-Type": "application/x-www-form-urlencoded"}
                )
                assert r.status_code == 303
                cookie = r.headers["set-cookie"].lower()
                assert "httponly" in cookie and "samesite=strict" in cookie and "secure" in cookie
        finally:
            running.stop()


def test_a_bad_certificate_is_one_clear_error(bus_pair_configs, tmp_path):
    cert, _key = _self_signed(tmp_path)
    listen_cfg, _ = bus_pair_configs
    with Bus(listen_cfg, service="dashboard") as bus:
        cfg = DashboardConfig(bus=listen_cfg, port=0, tls_certfile=str(cert), tls_keyfile=str(cert))
        with pytest.raises(UserError, match="not a usable certificate and key"):
            start(bus, cfg, Tokens())
        with pytest.raises(UserError, match="go together"):
            start(bus, DashboardConfig(bus=listen_cfg, port=0, tls_certfile=str(cert)), Tokens())
