"""`python -m tiplog.health SERVICE`: exit 0 when SERVICE's liveliness token is on the bus, 1
when it is not (compose's health check; the bus from the usual configuration and environment,
e.g. TIPLOG_BUS__CONNECT). A service declares its token once its bus session is open and
withdraws it when it stops or dies, so the check follows the service itself, not its port."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from tiplog.bus import Bus
from tiplog.config import ConfigError, ServiceConfig, load_config
from tiplog.service import add_config_arguments, overrides_from_args


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tiplog.health", description=__doc__.split("\n")[0])
    p.add_argument("service", help="name of the service (its liveliness token alive/<service>)")
    p.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for the bus and the token")
    add_config_arguments(p)
    args = p.parse_args(argv)
    try:
        cfg = load_config(ServiceConfig, "health", args.config, [*overrides_from_args(args)])
    except ConfigError as e:
        print(str(e), file=sys.stderr)
        return 2
    bus_cfg = cfg.bus.model_copy(update={"open_timeout_s": args.timeout})
    try:
        with Bus(bus_cfg) as bus:
            alive = bus.alive(args.timeout)
    except ConnectionError as e:
        print(f"unhealthy: {e}", file=sys.stderr)
        return 1
    if args.service in alive:
        return 0
    print(
        f"unhealthy: no liveliness token for {args.service} (alive: {', '.join(sorted(alive)) or 'none'})",
        file=sys.stderr,
    )
    return 1


if __name__ == "__main__":
    sys.exit(main())
