"""Configuration: YAML file, then environment, then command-line overrides, validated once.

One YAML file serves the whole system: a `bus:` section shared by every service and one
section per service named after it (`sensor_gateway:`, `fusion:`, ...). A service reads
`bus` and its own section. Environment variables `TIPLOG_<SECTION>__<FIELD>=value` and
`--set section.field=value` override the file; values are parsed as YAML scalars.

A bad value raises `ConfigError` whose message is one line per problem, naming the section and
field (`fusion.status_period_s`, `bus.connect`) and what is allowed; services turn it into exit
status 2.
"""

from __future__ import annotations

import ipaddress
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from tiplog.bus import BusConfig
from tiplog.userio import yaml_error_at

T = TypeVar("T", bound=BaseModel)
ENV_PREFIX = "TIPLOG_"


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of range."""


class ServiceConfig(BaseModel):
    """Fields every service has; each service subclasses it with its own."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    bus: BusConfig = Field(default_factory=BusConfig)
    log_level: str = Field("INFO", pattern="^(DEBUG|INFO|WARNING|ERROR)$")
    status_period_s: float = Field(1.0, gt=0.0, le=60.0)


def set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    """Set data['a']['b'] = value for dotted 'a.b', creating sections as needed."""
    parts = [p for p in dotted.split(".") if p]
    if not parts:
        raise ConfigError(f"override {dotted!r}: empty field name")
    node = data
    for p in parts[:-1]:
        nxt = node.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise ConfigError(f"override {dotted!r}: {p} is not a section")
        node = nxt
    node[parts[-1]] = value


def parse_override(text: str) -> tuple[str, Any]:
    """'section.field=value' -> ('section.field', parsed YAML value)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r} is not of the form field=value")
    key, raw = text.split("=", 1)
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as e:
        raise ConfigError(f"override {key}: value {raw!r} is not valid YAML ({e.__class__.__name__})") from None
    return key.strip(), value


def format_validation_error(err: ValidationError | list[dict[str, Any]], where: str = "", section: str = "") -> str:
    """One line per problem, `config error: LOCATION: what (got VALUE)`. `where` prefixes every
    location; `section` names the YAML section of a service's configuration, except for the
    shared `bus` section's fields, which are named as `bus.FIELD`."""
    lines = []
    for e in err.errors() if isinstance(err, ValidationError) else err:
        loc = ".".join(str(p) for p in e["loc"]) or "(root)"
        if section and not (e["loc"] and e["loc"][0] == "bus"):
            loc = f"{section}.{loc}" if loc != "(root)" else section
        if where:
            loc = f"{where}.{loc}" if loc != "(root)" else where
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown field"
        got = e.get("input")
        got_s = f" (got {got!r})" if got is not None and not isinstance(got, dict) else ""
        lines.append(f"config error: {loc}: {msg}{got_s}")
    return "\n".join(lines)


def read_yaml_file(path: str | Path, what: str = "config") -> Any:
    """The parsed YAML document of `path`; ConfigError naming the file (and the line and column
    of a syntax error) when it is missing, a folder, unreadable, empty, binary or not YAML."""
    p = Path(path)
    try:
        text = p.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{what} error: file {p} does not exist") from None
    except IsADirectoryError:
        raise ConfigError(f"{what} error: {p} is a folder, expected a YAML file") from None
    except OSError as e:
        raise ConfigError(f"{what} error: cannot read {p} ({e.strerror or e})") from None
    if not text.strip():
        raise ConfigError(f"{what} error: {p} is empty")
    try:
        return yaml.safe_load(text.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise ConfigError(f"{what} error: {p} is not a text file (byte {e.start} is not UTF-8)") from None
    except yaml.YAMLError as e:
        raise ConfigError(f"{what} error: {p} is not valid YAML{yaml_error_at(e)}") from None


def load_section(path: str | Path | None, section: str) -> dict[str, Any]:
    """{'bus': ..., **<section>} from the YAML file (empty when no file)."""
    if path is None:
        return {}
    p = Path(path)
    doc = read_yaml_file(p)
    if not isinstance(doc, dict):
        raise ConfigError(f"config error: {p} must hold a mapping of sections")
    out: dict[str, Any] = {}
    if "bus" in doc:
        out["bus"] = doc["bus"]
    sec = doc.get(section) or {}
    if not isinstance(sec, dict):
        raise ConfigError(f"config error: section {section!r} in {p} must be a mapping")
    out.update(sec)
    return out


def env_overrides(section: str, env: Mapping[str, str] | None = None) -> list[tuple[str, Any]]:
    """Overrides from TIPLOG_BUS__MODE / TIPLOG_<SECTION>__FIELD__SUB variables."""
    env = os.environ if env is None else env
    out = []
    sec_prefix = f"{ENV_PREFIX}{section.upper()}__"
    bus_prefix = f"{ENV_PREFIX}BUS__"
    for k, v in env.items():
        if k.startswith(bus_prefix):
            out.append(("bus." + k[len(bus_prefix) :].lower().replace("__", "."), yaml.safe_load(v)))
        elif k.startswith(sec_prefix):
            out.append((k[len(sec_prefix) :].lower().replace("__", "."), yaml.safe_load(v)))
    return out


def config_data(
    section: str,
    path: str | Path | None = None,
    overrides: Iterable[str | tuple[str, Any]] = (),
    env: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """A section's values from file, environment and overrides (later wins), not yet validated."""
    data = load_section(path, section)
    pairs: list[tuple[str, Any]] = env_overrides(section, env)
    for o in overrides:
        pairs.append(parse_override(o) if isinstance(o, str) else o)
    for key, value in pairs:
        set_path(data, key, value)
    return data


def load_config(
    model: type[T],
    section: str,
    path: str | Path | None = None,
    overrides: Iterable[str | tuple[str, Any]] = (),
    env: Mapping[str, str] | None = None,
) -> T:
    """Build and validate `model` from file, environment and overrides (later wins)."""
    data = config_data(section, path, overrides, env)
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise ConfigError(format_validation_error(e, section=section)) from None


def dump(config: BaseModel) -> str:
    """The resolved configuration as one line of JSON, for the log and the recorder."""
    return config.model_dump_json()


def host_is_loopback(host: str) -> bool:
    """127.0.0.0/8, ::1 and 'localhost' are loopback; anything else (0.0.0.0 above all) is not:
    what a service with no authentication binds to unless told to serve a network."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
