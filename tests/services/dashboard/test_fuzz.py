"""An API fuzz run: schemathesis against the dashboard's OpenAPI schema, with an operator token,
a real recorder behind the recorder routes: no 5xx, responses as documented, no traceback."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time

import httpx
import pytest
import yaml

from tests.conftest import ROOT, free_port
from tests.services.dashboard.live_system import OPERATOR_TOKEN, VIEWER_TOKEN
from tiplog.bus import Bus

pytestmark = pytest.mark.slow


def test_schemathesis_finds_no_server_error(bus_pair_configs, tmp_path):
    st = shutil.which("schemathesis", path=str(ROOT / ".venv" / "bin")) or shutil.which("schemathesis")
    if st is None:
        pytest.skip("schemathesis is not installed (pip install -e '.[dev]')")
    listen_cfg, _ = bus_pair_configs
    port = free_port()
    cfg = tmp_path / "system.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "recorder": {"out_dir": str(tmp_path / "rec"), "autostart": "never", "min_free_bytes": 0},
                "dashboard": {"port": port},
            }
        )
    )
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT),
        "TIPLOG_DASHBOARD_VIEWER_TOKEN": VIEWER_TOKEN,
        "TIPLOG_DASHBOARD_OPERATOR_TOKEN": OPERATOR_TOKEN,
    }
    common = ["-c", str(cfg), "--connect", listen_cfg.listen[0], "--prefix", listen_cfg.prefix]
    logs = {n: tmp_path / f"{n}.log" for n in ("recorder", "dashboard")}
    with Bus(listen_cfg):
        procs = {
            n: subprocess.Popen(
                [sys.executable, "-m", f"services.{n}", *common], cwd=ROOT, env=env, stderr=logs[n].open("w")
            )
            for n in ("recorder", "dashboard")
        }
        try:
            url = f"http://127.0.0.1:{port}"
            with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {OPERATOR_TOKEN}"}) as c:
                deadline = time.monotonic() + 60
                while True:  # until the dashboard answers and reaches the recorder
                    try:
                        if c.get("/api/recorder").status_code == 200:
                            break
                    except httpx.HTTPError:
                        pass
                    assert time.monotonic() < deadline, logs["dashboard"].read_text()
                    time.sleep(0.2)
            run = subprocess.run(
                [st, "run", f"{url}/openapi.json", "-H", f"Authorization: Bearer {OPERATOR_TOKEN}"]
                + ["--checks", "not_a_server_error,status_code_conformance,response_schema_conformance"]
                + ["--max-examples", "25", "--seed", "1", "--request-timeout", "10"],
                cwd=tmp_path,
                env=env,
                capture_output=True,
                text=True,
                timeout=300,
            )
        finally:
            for p in procs.values():
                p.terminate()
            for p in procs.values():
                p.wait(10)
    summary = run.stdout[-3000:]
    assert run.returncode == 0, summary
    assert "Tested: 8" in run.stdout, summary  # every operation in the schema
    assert list((tmp_path / "rec").rglob("*.mcap")), "no fuzzed start ever reached the recorder"
    for n, log in logs.items():
        assert "Traceback" not in log.read_text(), f"{n} logged a traceback"
