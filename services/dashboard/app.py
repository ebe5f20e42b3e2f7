"""`python -m services.dashboard`: joins the bus and declares its liveliness token; its own work
lands with its issue."""

from __future__ import annotations

from collections.abc import Sequence

from tiplog.config import ServiceConfig
from tiplog.service import idle_until_stopped, run_service

NAME = "dashboard"


class DashboardConfig(ServiceConfig):
    """Configuration of the dashboard service (section `dashboard:` of the YAML file)."""


def main(argv: Sequence[str] | None = None) -> int:
    return run_service(NAME, DashboardConfig, idle_until_stopped, argv, description=__doc__)
