"""Reading a simulated session back for the fidelity report: sensor arrays, ground truth
(bench/robot) and the constants from the file's metadata; truth interpolation, the
stationary windows and pose clustering."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from services.bench.sensors.calibration import BenchConstants
from tiplog.geometry import quat_to_rot, so3_exp, so3_log
from tiplog.mcap_io import read_messages, read_metadata

REST = ("pre", "post", "hold")


@dataclass
class Session:
    """Arrays read back from a session file."""

    meta: dict[str, Any]
    truth: BenchConstants
    calib: BenchConstants
    trials: list[dict]
    robot_t: np.ndarray
    robot_p: np.ndarray
    robot_R: np.ndarray
    robot_phase: np.ndarray
    streams: dict[str, dict[str, np.ndarray]]
    vision: dict[str, np.ndarray]
    motion_rate_hz: float


def _vec(v) -> list[float]:
    return [v.x, v.y, v.z]


def load(path: str | Path) -> Session:
    md = read_metadata(path)
    truth = BenchConstants.from_dict(json.loads(md["calibration_truth"]["json"]))
    calib = BenchConstants.from_dict(json.loads(md["calibration_as_calibrated"]["json"]))
    scen = yaml.safe_load(md["scenario"]["yaml"])
    trials = json.loads(md.get("trials", {}).get("json", "[]"))
    rob: dict[str, list] = {"t": [], "p": [], "q": [], "ph": []}
    raw: dict[str, dict[str, list]] = {
        k: {"t": [], "v": [], "s": [], "sm": [], "sv": []} for k in ("gyro", "accel", "tof", "mag")
    }
    vis: dict[str, list] = {k: [] for k in ("t", "acc", "nl", "nr", "ju", "jv", "jvis", "proc")}
    for r in read_messages(path):
        m = r.message
        if r.topic == "bench/robot":
            rob["t"].append(m.header.stamp_ns)
            rob["p"].append(_vec(m.tip_m))
            o = m.tool_pose.orientation
            rob["q"].append([o.x, o.y, o.z, o.w])
            rob["ph"].append(m.phase)
        elif r.topic == "device/tof":
            d = raw["tof"]
            d["t"].append(m.header.stamp_ns)
            d["v"].append(m.range_raw_mm)
            d["s"].append(m.status)
            d["sm"].append(m.range_smoothed_mm)
            d["sv"].append(m.smoothed_valid)
        elif r.topic.startswith("device/"):
            key = r.topic.split("/")[1]
            if key in raw:
                raw[key]["t"].append(m.header.stamp_ns)
                f = {"gyro": m.rate_radps if key == "gyro" else None}
                vec = f["gyro"] if key == "gyro" else (m.specific_force_mps2 if key == "accel" else m.field_ut)
                raw[key]["v"].append(_vec(vec))
        elif r.topic == "vision/observation":
            vis["t"].append(m.header.stamp_ns)
            vis["acc"].append(m.accepted)
            vis["nl"].append(_vec(m.n_left))
            vis["nr"].append(_vec(m.n_right))
            vis["ju"].append(m.junction_u_px)
            vis["jv"].append(m.junction_v_px)
            vis["jvis"].append(m.junction_visible)
            vis["proc"].append(m.processing_ms)
    streams = {k: {kk: np.asarray(vv) for kk, vv in d.items()} for k, d in raw.items()}
    return Session(
        meta=md,
        truth=truth,
        calib=calib,
        trials=trials,
        robot_t=np.asarray(rob["t"], dtype=np.int64),
        robot_p=np.asarray(rob["p"], dtype=float).reshape(-1, 3),
        robot_R=quat_to_rot(np.asarray(rob["q"], dtype=float).reshape(-1, 4)),
        robot_phase=np.asarray(rob["ph"]),
        streams=streams,
        vision={k: np.asarray(v) for k, v in vis.items()},
        motion_rate_hz=float(scen.get("motion", {}).get("rate_hz", 1000.0)),
    )


# --- truth at arbitrary times ---------------------------------------------------------------
def truth_p(s: Session, t_ns: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t_ns, s.robot_t, s.robot_p[:, j]) for j in range(3)], -1)


def truth_R(s: Session, t_ns: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(s.robot_t, t_ns, side="right") - 1, 0, len(s.robot_t) - 2)
    a = np.clip((t_ns - s.robot_t[i]) / np.diff(s.robot_t)[i], 0.0, 1.0)
    rel = so3_log(np.einsum("nji,njk->nik", s.robot_R[i], s.robot_R[i + 1]))
    return s.robot_R[i] @ so3_exp(a[:, None] * rel)


def rest_windows(s: Session, trim_s: float = 0.5, min_s: float = 2.0) -> list[tuple[int, int]]:
    """(start_ns, end_ns) of the stationary windows (pre/post/hold runs), trimmed."""
    rest = np.isin(s.robot_phase, REST)
    out = []
    if not rest.any():
        return out
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rest.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        t0, t1 = s.robot_t[a] + trim_s * 1e9, s.robot_t[b - 1] - trim_s * 1e9
        if t1 - t0 >= (min_s - 2 * trim_s) * 1e9 and np.ptp(s.robot_p[a:b], axis=0).max() < 1e-4:
            out.append((int(t0), int(t1)))
    return out


def in_window(t: np.ndarray, w: tuple[int, int]) -> np.ndarray:
    return (t >= w[0]) & (t <= w[1])


def pose_key(s: Session, tm: np.ndarray) -> np.ndarray:
    """Tip [mm] and rotation matrix entries scaled so that 0.2 units ~ 0.2 mm ~ 0.1 deg."""
    return np.concatenate([truth_p(s, tm)[0] * 1e3, truth_R(s, tm)[0].ravel() * 114.6])


def cluster_poses(P: np.ndarray, tol: float = 0.2) -> np.ndarray:
    """Label windows that revisit one pose (within tol in every pose_key entry)."""
    labels = -np.ones(len(P), int)
    for i in range(len(P)):
        if labels[i] < 0:
            labels[(labels < 0) & (np.abs(P - P[i]).max(1) < tol)] = labels.max() + 1
    return labels
