"""CSV in the JIGSAWS kinematics layout, one row per frame, for skill-assessment tools.

JIGSAWS gives each manipulator 19 columns: position (3), rotation matrix (9, row-major), linear
velocity (3), angular velocity (3) and the gripper angle. Here the one tool is `tool`:
`tool_pos_{x,y,z}_m` (the tip, base frame), `tool_rot_{11..33}` (R_base_tool, its third column
the shaft direction), `tool_vel_{x,y,z}_mps` (the tip), `tool_angvel_{x,y,z}_radps` (base
frame, from the orientations), `tool_gripper_angle_rad` (empty: no jaw sensor). Before them:
`time_s` (the segment's frame grid, seconds), `stamp_ns` (the state's host-clock stamp),
`segment`, `valid` (0: no state within half a frame of the grid time; the row's values are
empty); after them tiplog's own: `depth_mm`, `tilt_deg`, `roll_deg`, `tip_sigma_{x,y,z}_mm`,
`vision_locked`.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

from tiplog.export.track import Frames, Track

TOOL = "tool"
_ROT = [f"{TOOL}_rot_{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)]
COLUMNS = [
    "time_s", "stamp_ns", "segment", "valid",
    f"{TOOL}_pos_x_m", f"{TOOL}_pos_y_m", f"{TOOL}_pos_z_m", *_ROT,
    f"{TOOL}_vel_x_mps", f"{TOOL}_vel_y_mps", f"{TOOL}_vel_z_mps",
    f"{TOOL}_angvel_x_radps", f"{TOOL}_angvel_y_radps", f"{TOOL}_angvel_z_radps",
    f"{TOOL}_gripper_angle_rad",
    "depth_mm", "tilt_deg", "roll_deg", "tip_sigma_x_mm", "tip_sigma_y_mm", "tip_sigma_z_mm", "vision_locked",
]  # fmt: skip


def write_csv(path: Path, track: Track, segments: Sequence[Frames]) -> int:
    """Write the frames of every segment; returns the row count."""
    R = track.R_base_tool
    n = 0
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for seg in segments:
            for t, row, ok in zip(seg.time_s, seg.index, seg.valid, strict=True):
                head = [f"{t:.6f}", int(track.t_ns[row]) if ok else "", seg.segment, int(ok)]
                if not ok:
                    w.writerow(head + [""] * (len(COLUMNS) - len(head)))
                    n += 1
                    continue
                vals = [
                    *track.p_tip_base_m[row], *R[row].ravel(), *track.v_tip_base_mps[row], *track.w_base_radps[row],
                ]  # fmt: skip
                extra = [track.depth_mm[row], track.tilt_deg[row], track.roll_deg[row], *track.tip_sigma_mm[row]]
                w.writerow(
                    head + [repr(float(v)) for v in vals] + [""] + [repr(float(v)) for v in extra]
                    + [int(track.vision_locked[row])]
                )  # fmt: skip
                n += 1
    return n
