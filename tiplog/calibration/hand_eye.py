"""`tiplog calibrate hand-eye POSES.csv`: the camera's pose in the robot base from pairs of
robot tool poses and marker poses detected in the camera.

CSV, one row per pose, header required, positions in metres, quaternions (x, y, z, w):
  tool_x_m, tool_y_m, tool_z_m, tool_qx, tool_qy, tool_qz, tool_qw      T_base_tool (robot)
  marker_x_m, marker_y_m, marker_z_m, marker_qx, marker_qy, marker_qz, marker_qw
                                                                        T_camera_marker (e.g. ArUco)
The last --heldout rows are kept out of the fit and scored (the paper: 30 fitted, 20 held out).
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path

import numpy as np
import yaml

from tiplog.calibration import Calibration, CalibrationError
from tiplog.calibration.fits.hand_eye import fit_hand_eye
from tiplog.cliargs import whole
from tiplog.geometry import quat_to_rot, rot_to_quat
from tiplog.userio import UserError, atomic_output, input_file, output_file

TOOL = ("tool_x_m", "tool_y_m", "tool_z_m", "tool_qx", "tool_qy", "tool_qz", "tool_qw")
MIN_FIT_POSES = 3  # fit_hand_eye's minimum
MARKER = ("marker_x_m", "marker_y_m", "marker_z_m", "marker_qx", "marker_qy", "marker_qz", "marker_qw")


def _poses(rows: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = quat_to_rot(rows[:, 3:7])
    T[:, :3, 3] = rows[:, :3]
    return T


def read_pose_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(T_base_tool, T_camera_marker), each (n, 4, 4), from the documented CSV."""
    p = input_file(path, "pose CSV file")
    try:
        text = p.read_text()
    except UnicodeDecodeError:
        raise UserError(f"{p}: not a text CSV file (expected the pose CSV described in docs/calibration.md)") from None
    reader = csv.DictReader(io.StringIO(text, newline=""))
    missing = [c for c in TOOL + MARKER if c not in (reader.fieldnames or [])]
    if missing:
        raise UserError(f"{p}: missing column(s) {', '.join(missing)}")
    vals = []
    for row in reader:
        try:
            vals.append([float(row[c]) for c in TOOL + MARKER])
        except (TypeError, ValueError):
            raise UserError(f"{p}: line {reader.line_num}: every pose column must be a number") from None
    a = np.asarray(vals, dtype=float).reshape(-1, 14)
    if not np.all(np.isfinite(a)):
        raise UserError(f"{p}: non-finite value in a pose column")
    for name, q in (("tool", a[:, 3:7]), ("marker", a[:, 10:14])):
        bad = np.flatnonzero(np.abs(np.linalg.norm(q, axis=1) - 1.0) > 1e-3)
        if len(bad):
            raise UserError(f"{p}: line {bad[0] + 2}: {name} quaternion is not unit length")
    return _poses(a[:, :7]), _poses(a[:, 7:])


def write_pose_csv(path: str | Path, T_base_tool: np.ndarray, T_camera_marker: np.ndarray) -> None:
    """The CSV `read_pose_csv` reads (for tests and for tools that record poses)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(TOOL + MARKER)
        for B, C in zip(T_base_tool, T_camera_marker, strict=True):
            w.writerow([*B[:3, 3], *rot_to_quat(B[:3, :3]), *C[:3, 3], *rot_to_quat(C[:3, :3])])


def run(args: argparse.Namespace) -> int:
    # the inputs first, then --out, which must not be one of them: refused before any work
    poses = input_file(args.poses, "pose CSV file")
    base_file = input_file(args.base, "calibration file") if args.base else None
    output_file(args.out, args.force)
    base = None
    if base_file is not None:
        try:
            base = Calibration.load_yaml(base_file)
        except CalibrationError as e:
            raise UserError(str(e)) from None
    B, C = read_pose_csv(poses)
    if args.heldout and len(B) - args.heldout < MIN_FIT_POSES:
        raise UserError(
            f"--heldout {args.heldout} leaves {max(len(B) - args.heldout, 0)} of the {len(B)} poses in "
            f"{args.poses} to fit (need at least {MIN_FIT_POSES})"
        )
    res = fit_hand_eye(B, C, heldout=args.heldout)
    report = {
        "poses": res.poses,
        "heldout_poses": res.heldout_poses,
        "fit_mean_mm": round(res.fit_mean_mm, 3),
        "fit_mean_deg": round(res.fit_mean_deg, 3),
        "heldout_mean_mm": round(res.heldout_mean_mm, 3),
        "heldout_mean_deg": round(res.heldout_mean_deg, 3),
        "T_tool_marker": res.T_tool_marker.tolist(),
    }
    with atomic_output(args.out, args.force) as tmp:
        if base is not None:
            import dataclasses

            dataclasses.replace(base, T_base_camera=res.T_base_camera).save_yaml(tmp, extra={"hand_eye": report})
        else:
            doc = {"hand_eye": {"T_base_camera": res.T_base_camera.tolist(), **report}}
            tmp.write_text(yaml.safe_dump(doc, sort_keys=False))
    sys.stdout.write(yaml.safe_dump({k: v for k, v in report.items() if k != "T_tool_marker"}, sort_keys=False))
    sys.stdout.write(f"wrote {args.out}\n")
    return 0


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("poses", help="CSV of robot tool poses and detected marker poses (see docs/calibration.md)")
    p.add_argument("--out", required=True, help="YAML to write: a calibration file with --base, else the result alone")
    p.add_argument("--base", help="calibration file whose T_base_camera the result replaces")
    p.add_argument(
        "--heldout", type=whole(0), default=0, metavar="N", help="score the last N poses instead of fitting them"
    )
    p.add_argument("--force", action="store_true", help="overwrite --out")
    p.set_defaults(func=run)
