"""`tiplog calibrate`: calibration constants from a fit-only session."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", help="fit-only block (ten static poses) as MCAP")
    p.add_argument("--out", default="calibration.yaml", help="calibration file to write")
    p.add_argument("--what", default="all", help="comma list: accel, mounting, tof, vision_offset, latency, all")
    p.set_defaults(func=not_yet("calibration", "the calibration issue"))
