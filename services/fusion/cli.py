"""`tiplog fusion`: the filter offline on a recording."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", help="MCAP file with device and vision topics")
    p.add_argument("--out", help="MCAP or CSV file for the estimated trajectory")
    p.add_argument(
        "--sensors", default="full", help="sensor subset: full, imu_tof, imu_vision, vision (comma list allowed)"
    )
    p.add_argument("--calibration", help="calibration file (default: the recording's as-calibrated constants)")
    p.add_argument("--params", help="YAML file of filter parameters")
    p.set_defaults(func=not_yet("offline fusion", "the fusion issue"))
