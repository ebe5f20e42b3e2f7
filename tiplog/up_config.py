"""The system's configuration as `tiplog up` checks it before it starts anything: every section
of the YAML file known, every service's section valid by that service's own model (with the
environment's `TIPLOG_<SECTION>__<FIELD>` overrides, which the services inherit).

A service's model is found in `services.<name>.config` or else `services.<name>.app` (the
first `ServiceConfig` subclass there), so that checking costs imports, not a start.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable, Mapping
from pathlib import Path

from pydantic import ValidationError

from tiplog.config import ConfigError, ServiceConfig, config_data, format_validation_error, read_yaml_file

SERVICES = ("bench", "sensor_gateway", "vision", "fusion", "recorder", "dashboard", "igtlink")
# Sections read by the programs beside the services: the router (compose), the health check, replay.
TOOLS = ("router", "health", "replay")
SECTIONS = ("bus", *SERVICES, *TOOLS)


def config_model(name: str) -> type[ServiceConfig] | None:
    """A service's configuration model (None when it cannot be imported here)."""
    for module in (f"services.{name}.config", f"services.{name}.app"):
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as e:
            if e.name == module:
                continue
            return None  # a service that fails to import says so itself when started
        except Exception:
            return None
        for v in vars(mod).values():
            if isinstance(v, type) and issubclass(v, ServiceConfig) and v is not ServiceConfig:
                return v
    return None


def check_system_config(
    path: str | Path | None,
    names: Iterable[str],
    sets: Mapping[str, list[str]] | None = None,
    pending: str | Path | None = None,
    env: Mapping[str, str] | None = None,
) -> None:
    """ConfigError, one line per problem naming section and field, when the file has a section
    no program reads, or the section of a service in `names` (or of a tool present in the file)
    does not validate with `sets[name]` (`field=value` overrides) applied. A value
    equal to `pending` names a file written once the system runs (the bench's calibration):
    what is said of it is not a problem yet."""
    sections: set[str] = set()
    if path is not None:
        doc = read_yaml_file(path)
        if not isinstance(doc, dict):
            raise ConfigError(f"config error: {path} must hold a mapping of sections")
        unknown = [str(k) for k in doc if k not in SECTIONS]
        if unknown:
            raise ConfigError(
                "\n".join(
                    f"config error: {k}: unknown section in {path} (sections: {', '.join(SECTIONS)})" for k in unknown
                )
            )
        sections = set(doc)
    problems: list[str] = []
    for name in [*SERVICES, *TOOLS]:
        if name not in names and not (name in TOOLS and name in sections):
            continue
        model = ServiceConfig if name in TOOLS else config_model(name)
        if model is None:
            continue
        try:
            model.model_validate(config_data(name, path, (sets or {}).get(name, ()), env))
        except ValidationError as e:
            errors = [err for err in e.errors() if pending is None or err.get("input") != str(pending)]
            if errors:
                # The shared bus section is named once, by the first service that reads it.
                text = format_validation_error(errors, section=name)
                problems += [line for line in text.splitlines() if line not in problems]
    if problems:
        raise ConfigError("\n".join(problems))
