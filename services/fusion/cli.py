"""`tiplog fusion`: the filter offline on a recording (`run`), and the IMU's attitude alone
(`attitude`). Each action's arguments and work live in its own module."""

from __future__ import annotations

import argparse

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
