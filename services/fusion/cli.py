"""`tiplog fusion`: the filter offline on a recording (`run`), the IMU's attitude alone
(`attitude`), and the filter's built-in parameters (`params`). Each action's arguments and work
live in its own module."""

from __future__ import annotations

import argparse
import sys

from services.fusion.attitude import cli as attitude_cli
from services.fusion.offline import run as run_cli


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="fusion_command", metavar="ACTION", required=True)
    run_cli.register(sub.add_parser("run", help="the tracking filter over a recording", description=run_cli.__doc__))
    attitude_cli.register(
        sub.add_parser(
            "attitude",
            help="orientation from a CSV of gyro and accelerometer samples",
            description=attitude_cli.__doc__,
        )
    )
    pp = sub.add_parser(
        "params",
        help="the built-in filter parameters: a YAML file to start --params from",
        description="Print the built-in filter parameters as a --params YAML file, each with its unit and "
        "what it does; --markdown prints the parameter table of docs/fusion.md instead.",
    )
    pp.add_argument("--markdown", action="store_true", help="the table of docs/fusion.md instead of YAML")
    pp.set_defaults(func=_params)


def _params(args: argparse.Namespace) -> int:
    from services.fusion.params_file import defaults_yaml, markdown_table

    sys.stdout.write(markdown_table() if args.markdown else defaults_yaml())
    return 0
