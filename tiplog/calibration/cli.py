"""`tiplog calibrate`: calibration constants from recordings, written to one YAML file that
`tiplog fusion run --calibration FILE` reads.

Actions:
  block SESSION.mcap --out cal.yaml     fit-only block against the robot reference: RCM, IMU
                                        mounting, accelerometer, ToF ray-plane, vision tip offset
                                        (+ --latency LAT.mcap: each stream's latency by lock-in)
  latency LAT.mcap                      lock-in latency table of a latency-protocol recording
  hand-eye POSES.csv --out he.yaml      AX = XB from robot poses and marker poses in the camera
  intrinsics IMAGES --out cam.yaml      camera intrinsics from chessboard views (folder or MCAP)
"""

from __future__ import annotations

import argparse
import json
import sys

import yaml

from tiplog.calibration import block as calibrate_block
from tiplog.calibration import data as calibrate_data
from tiplog.calibration import hand_eye as calibrate_hand_eye
from tiplog.calibration import intrinsics as calibrate_intrinsics
from tiplog.calibration.fits import DegenerateDataError
from tiplog.userio import UserError, atomic_output, input_file, input_mcap, output_file


def _out(s: str) -> None:
    sys.stdout.write(s + "\n")


def _fits(text: str) -> tuple[str, ...]:
    names = tuple(x.strip() for x in text.split(",") if x.strip())
    if names == ("all",):
        return calibrate_block.BLOCK_FITS
    bad = [n for n in names if n not in calibrate_block.BLOCK_FITS]
    if bad or not names:
        raise UserError(
            f"--fits: unknown fit(s) {', '.join(bad) or '(none)'}; choose from all, {', '.join(calibrate_block.BLOCK_FITS)}"
        )
    return names


def _inputs_then_output(args: argparse.Namespace) -> None:
    """Check the inputs, then --out, which must not be one of them; before any work."""
    for rec in (args.recording, getattr(args, "latency", None)):
        if rec:
            input_mcap(rec)
    if args.prior:
        input_file(args.prior, "calibration file")
    if args.out:
        output_file(args.out, args.force)


def run_block(args: argparse.Namespace) -> int:
    fits = _fits(args.fits)
    _inputs_then_output(args)
    data = calibrate_data.load(args.recording, args.prior)
    cal, report = calibrate_block.calibrate_block(data, fits)
    if args.latency:
        from tiplog.calibration import latency as calibrate_latency

        lat_data = calibrate_data.load(args.latency, args.prior)
        table = calibrate_latency.latency_table(lat_data, cal)
        cal = calibrate_latency.apply(cal, table)
        report["latency"] = table
    with atomic_output(args.out, args.force) as tmp:
        cal.save_yaml(tmp, extra=report)
    _out(json.dumps(report, indent=1) if args.json else yaml.safe_dump(report, sort_keys=False).rstrip())
    _out(f"wrote {args.out}")
    return 0


def run_latency(args: argparse.Namespace) -> int:
    from tiplog.calibration import latency as calibrate_latency

    _inputs_then_output(args)
    data = calibrate_data.load(args.recording, args.prior)
    if data.prior is None:
        raise DegenerateDataError("latency: no starting constants: give --prior FILE")
    table = calibrate_latency.latency_table(data, data.prior)
    _out(calibrate_latency.markdown(table))
    if args.out:
        with atomic_output(args.out, args.force) as tmp:
            tmp.write_text(json.dumps(table, indent=1))
    return 0


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="calibrate_command", metavar="ACTION", required=True)
    b = sub.add_parser("block", help="fits of the fit-only block (ten static poses) -> calibration YAML")
    b.add_argument("recording", help="fit-only block with the robot reference (MCAP)")
    b.add_argument("--out", required=True, help="calibration file to write (YAML)")
    b.add_argument("--prior", help="starting constants (calibration YAML); default: the recording's own")
    b.add_argument("--fits", default="all", help=f"comma list of: all, {', '.join(calibrate_block.BLOCK_FITS)}")
    b.add_argument("--latency", help="latency-protocol recording: also fit each stream's latency")
    b.add_argument("--json", action="store_true", help="print the report as JSON")
    b.add_argument("--force", action="store_true", help="overwrite --out")
    b.set_defaults(func=run_block)
    la = sub.add_parser("latency", help="each stream's latency by lock-in on a latency-protocol recording")
    la.add_argument("recording", help="latency-protocol recording with the robot reference (MCAP)")
    la.add_argument("--prior", help="constants to predict each stream from the robot (calibration YAML)")
    la.add_argument("--out", help="JSON file for the table")
    la.add_argument("--force", action="store_true")
    la.set_defaults(func=run_latency)
    calibrate_hand_eye.register(
        sub.add_parser("hand-eye", help="camera pose in the base: AX = XB from robot and marker poses (CSV)")
    )
    calibrate_intrinsics.register(
        sub.add_parser("intrinsics", help="camera intrinsics and distortion from chessboard views")
    )
