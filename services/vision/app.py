"""`python -m services.vision`: joins the bus and declares its liveliness token; its own work
lands with its issue."""

from __future__ import annotations

from collections.abc import Sequence

from tiplog.config import ServiceConfig
from tiplog.service import idle_until_stopped, run_service

NAME = "vision"


class VisionConfig(ServiceConfig):
    """Configuration of the vision service (section `vision:` of the YAML file)."""


def main(argv: Sequence[str] | None = None) -> int:
    return run_service(NAME, VisionConfig, idle_until_stopped, argv, description=__doc__)
