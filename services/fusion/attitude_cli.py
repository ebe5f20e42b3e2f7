"""`tiplog fusion attitude IN.csv OUT.csv`: the IMU's orientation alone (sensor to an earth
frame with z up, heading arbitrary)."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="CSV: t_s, gyr_x, gyr_y, gyr_z [rad/s], acc_x, acc_y, acc_z [m/s^2]")
    p.add_argument("output", help="CSV to write: t_s, qw, qx, qy, qz")
    p.set_defaults(func=not_yet("attitude estimation", "the fusion issue"))
