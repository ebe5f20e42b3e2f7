from __future__ import annotations

import pytest
from pydantic import Field

from tiplog.config import ConfigError, ServiceConfig, load_config


class DemoConfig(ServiceConfig):
    rate_hz: float = Field(200.0, gt=0, le=2000)
    port: str = "/dev/ttyACM0"


def test_file_env_and_overrides_in_order(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("bus:\n  mode: client\ndemo:\n  rate_hz: 100\n  port: /dev/ttyUSB0\nother:\n  rate_hz: -1\n")
    env = {"TIPLOG_DEMO__RATE_HZ": "150", "TIPLOG_BUS__PREFIX": "lab/"}
    c = load_config(DemoConfig, "demo", f, ["rate_hz=175"], env=env)
    assert c.bus.mode == "client"
    assert c.bus.prefix == "lab/"
    assert c.rate_hz == 175.0  # command line beats environment beats file
    assert c.port == "/dev/ttyUSB0"


def test_out_of_range_names_field_and_range():
    with pytest.raises(ConfigError) as e:
        load_config(DemoConfig, "demo", None, ["rate_hz=5000"], env={})
    msg = str(e.value)
    assert msg.count("\n") == 0
    assert "rate_hz" in msg and "2000" in msg and "5000" in msg


def test_unknown_field_and_bad_enum():
    with pytest.raises(ConfigError, match=r"config error: demo\.rate: unknown field"):
        load_config(DemoConfig, "demo", None, ["rate=3"], env={})
    with pytest.raises(ConfigError, match=r"bus\.mode: .*'peer'.*'client'.*'router'"):
        load_config(DemoConfig, "demo", None, ["bus.mode=mesh"], env={})


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(DemoConfig, "demo", tmp_path / "nope.yaml", env={})
    bad = tmp_path / "bad.yaml"
    bad.write_text("demo: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(DemoConfig, "demo", bad, env={})
