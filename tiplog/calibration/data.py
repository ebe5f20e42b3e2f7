"""A calibration recording read into arrays for tiplog.calibration.fits.

Calibration, unlike estimation, may use the robot reference (`bench/robot`: the tool pose,
as the paper calibrated against its FR3) and the protocol timing (`trials` metadata). It never
reads the bench's `calibration_truth`; the starting constants (`prior`) come from a
calibration file or the recording's `calibration`/`calibration_as_calibrated` metadata.
Stamps are host-clock ns; device and camera stamps are arrival (capture) stamps.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tiplog.calibration import Calibration, CalibrationError
from tiplog.geometry import quat_to_rot
from tiplog.mcap_io import read_messages, read_metadata
from tiplog.userio import UserError, input_file, input_mcap

TOPICS = (
    "bench/robot",
    "device/gyro",
    "device/accel",
    "device/tof",
    "device/mag",
    "vision/observation",
)
TOF_VALID = 1


def _v(m: Any) -> tuple[float, float, float]:
    return (m.x, m.y, m.z)


@dataclass
class CalibrationData:
    """Arrays of one recording: robot reference (n,), device streams, vision observations."""

    robot_t_ns: np.ndarray
    R_base_tool: np.ndarray  # (n, 3, 3)
    p_tip_base_m: np.ndarray  # (n, 3)
    robot_trial: np.ndarray  # (n,) int, -1 outside trials
    robot_phase: np.ndarray  # (n,) str
    gyro_t_ns: np.ndarray
    gyro_radps: np.ndarray  # (n, 3) imu frame
    accel_t_ns: np.ndarray
    accel_mps2: np.ndarray  # (n, 3) imu frame
    tof_t_ns: np.ndarray
    tof_raw_mm: np.ndarray
    tof_valid: np.ndarray  # (n,) bool
    tof_smoothed_mm: np.ndarray
    tof_smoothed_valid: np.ndarray
    mag_t_ns: np.ndarray
    mag_ut: np.ndarray  # (n, 3) imu frame
    vision: dict[str, np.ndarray]  # capture_ns, accepted, n_left, n_right, axis_point_m, junction_ray, junction_visible
    trials: list[dict[str, Any]] = field(default_factory=list)
    prior: Calibration | None = None
    source: str = ""

    @property
    def has_robot(self) -> bool:
        return len(self.robot_t_ns) > 0


def load(path: str | Path, prior_file: str | Path | None = None) -> CalibrationData:
    """Read `path` (MCAP); `prior_file` (calibration YAML) overrides the recording's own
    as-calibrated constants as the starting point. UserError for unreadable input."""
    p = input_mcap(path)
    try:
        meta = read_metadata(p)
    except UserError:
        raise
    except Exception as e:  # noqa: BLE001 - any reader failure is a bad file for the user
        raise UserError(f"{p}: cannot read the MCAP metadata ({e})") from None
    prior: Calibration | None = None
    try:
        if prior_file is not None:
            prior = Calibration.load_yaml(input_file(prior_file, "calibration file"))
        elif any(k in meta for k in ("calibration", "calibration_as_calibrated")):
            prior = Calibration.from_mcap_metadata(meta, where=str(p))
    except CalibrationError as e:
        raise UserError(str(e)) from None
    trials: list[dict[str, Any]] = []
    if "trials" in meta and "json" in meta["trials"]:
        try:
            trials = json.loads(meta["trials"]["json"])
        except ValueError:
            raise UserError(f"{p}: metadata 'trials' is not valid JSON") from None
    cols: dict[str, list] = {k: [] for k in ("rt", "rq", "rp", "rtr", "rph")}
    cols.update({k: [] for k in ("gt", "g", "at", "a", "tt", "tr", "tv", "ts", "tsv", "mt", "m")})
    vis: dict[str, list] = {
        k: []
        for k in ("capture_ns", "accepted", "n_left", "n_right", "axis_point_m", "junction_ray", "junction_visible")
    }
    try:
        for rec in read_messages(p, TOPICS):
            m, t = rec.message, rec.topic
            if t == "bench/robot":
                cols["rt"].append(m.header.stamp_ns)
                o = m.tool_pose.orientation
                cols["rq"].append((o.x, o.y, o.z, o.w))
                cols["rp"].append(_v(m.tool_pose.position_m))
                cols["rtr"].append(m.trial)
                cols["rph"].append(m.phase)
            elif t == "device/gyro":
                cols["gt"].append(m.header.stamp_ns)
                cols["g"].append(_v(m.rate_radps))
            elif t == "device/accel":
                cols["at"].append(m.header.stamp_ns)
                cols["a"].append(_v(m.specific_force_mps2))
            elif t == "device/tof":
                cols["tt"].append(m.header.stamp_ns)
                cols["tr"].append(m.range_raw_mm)
                cols["tv"].append(m.status == TOF_VALID)
                cols["ts"].append(m.range_smoothed_mm)
                cols["tsv"].append(m.smoothed_valid)
            elif t == "device/mag":
                cols["mt"].append(m.header.stamp_ns)
                cols["m"].append(_v(m.field_ut))
            else:
                vis["capture_ns"].append(m.header.stamp_ns)
                vis["accepted"].append(m.accepted)
                vis["n_left"].append(_v(m.n_left))
                vis["n_right"].append(_v(m.n_right))
                vis["axis_point_m"].append(_v(m.axis_point_m))
                vis["junction_ray"].append(_v(m.junction_ray))
                vis["junction_visible"].append(m.junction_visible)
    except UserError:
        raise
    except Exception as e:  # noqa: BLE001
        raise UserError(f"{p}: cannot read the recording ({e})") from None

    def arr(k: str, shape: tuple[int, ...] = (), dtype: Any = float) -> np.ndarray:
        return np.asarray(cols[k], dtype=dtype).reshape((len(cols[k]),) + shape)

    rq = arr("rq", (4,))
    return CalibrationData(
        robot_t_ns=arr("rt", (), np.int64),
        R_base_tool=quat_to_rot(rq) if len(rq) else np.zeros((0, 3, 3)),
        p_tip_base_m=arr("rp", (3,)),
        robot_trial=arr("rtr", (), np.int64),
        robot_phase=np.asarray(cols["rph"], dtype=str),
        gyro_t_ns=arr("gt", (), np.int64),
        gyro_radps=arr("g", (3,)),
        accel_t_ns=arr("at", (), np.int64),
        accel_mps2=arr("a", (3,)),
        tof_t_ns=arr("tt", (), np.int64),
        tof_raw_mm=arr("tr"),
        tof_valid=arr("tv", (), bool),
        tof_smoothed_mm=arr("ts"),
        tof_smoothed_valid=arr("tsv", (), bool),
        mag_t_ns=arr("mt", (), np.int64),
        mag_ut=arr("m", (3,)),
        vision={
            k: np.asarray(
                v, dtype=np.int64 if k == "capture_ns" else (bool if k in ("accepted", "junction_visible") else float)
            )
            for k, v in vis.items()
        },
        trials=trials,
        prior=prior,
        source=str(p),
    )
