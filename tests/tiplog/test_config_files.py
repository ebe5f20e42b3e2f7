"""A service's configuration file that is missing, a folder, empty, binary, not a mapping or
not valid YAML stops it with one line naming the file (and the line and column of a syntax
error), exit status 2, no traceback."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.conftest import ROOT
from tiplog.config import ConfigError, ServiceConfig, load_config
from tiplog.up import DEFAULT_SERVICES


def bad_files(d):
    (d / "folder.yaml").mkdir()
    (d / "empty.yaml").write_text("")
    (d / "binary.yaml").write_bytes(b"\x89MCAP0\r\n\x00\x01")
    (d / "list.yaml").write_text("- bus\n- fusion\n")
    (d / "syntax.yaml").write_text("bus:\n  mode: client\nfusion: [a, b\n")
    return {
        "missing.yaml": "does not exist",
        "folder.yaml": "is a folder",
        "empty.yaml": "is empty",
        "binary.yaml": "is not a text file",
        "list.yaml": "must hold a mapping",
        "syntax.yaml": "is not valid YAML at line 4, column 1",
    }


def test_every_bad_file_is_one_line_naming_it(tmp_path):
    for name, what in bad_files(tmp_path).items():
        with pytest.raises(ConfigError) as e:
            load_config(ServiceConfig, "fusion", tmp_path / name)
        msg = str(e.value)
        assert "\n" not in msg and name in msg and what in msg, msg


@pytest.mark.slow
@pytest.mark.parametrize("service", [*DEFAULT_SERVICES, "router"])
def test_each_service_stops_on_a_yaml_error_with_one_line(service, tmp_path):
    bad_files(tmp_path)
    module = "tiplog.router" if service == "router" else f"services.{service}"
    r = subprocess.run(
        [sys.executable, "-m", module, "-c", str(tmp_path / "syntax.yaml")],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=60,
    )
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert len(lines) == 1 and "syntax.yaml is not valid YAML at line 4, column 1" in lines[0], r.stderr
