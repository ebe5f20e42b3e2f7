"""`python -m tiplog.router`: a Zenoh session in router mode that the services connect to
(there is no router binary on the cart). Listens on tcp/0.0.0.0:7447 unless told otherwise."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from tiplog.config import ServiceConfig
from tiplog.service import idle_until_stopped, run_service


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    defaults = ["--mode", "router"]
    if not any(a in ("-l", "--listen") for a in argv):
        defaults += ["--listen", "tcp/0.0.0.0:7447"]
    if not any(a in ("-e", "--connect") for a in argv):
        defaults += ["--set", "bus.connect=[]"]
    return run_service("router", ServiceConfig, idle_until_stopped, defaults + argv, description=__doc__)


if __name__ == "__main__":
    sys.exit(main())
