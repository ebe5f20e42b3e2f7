"""Analytic ground-truth motions (the shape of services.bench.robot.motion.GroundTruth) for testing
the sensor and vision models without the robot."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tiplog.geometry import so3_exp


@dataclass
class Truth:
    t_ns: np.ndarray
    R_base_tool: np.ndarray
    p_tip_base_m: np.ndarray
    rcm_base_m: np.ndarray
    trial: np.ndarray
    phase: np.ndarray
    trials: list = field(default_factory=list)
    meta: dict = field(default_factory=dict)


def pivot(
    R0: np.ndarray,
    rcm: np.ndarray,
    depth_m: float,
    duration_s: float,
    axis_base: np.ndarray | None = None,
    angle_rad=None,
) -> Truth:
    """Shaft pivoting about the RCM: R(t) = Exp(angle(t) axis) R0, tip = rcm + depth R e_z.
    angle_rad: callable t_s -> angle (default: at rest)."""
    n = int(round(duration_s * 1000)) + 1
    t = np.arange(n) / 1000.0
    ang = np.zeros(n) if angle_rad is None else angle_rad(t)
    ax = np.array([1.0, 0.0, 0.0]) if axis_base is None else np.asarray(axis_base, float) / np.linalg.norm(axis_base)
    R = so3_exp(ang[:, None] * ax) @ R0
    p = rcm + depth_m * R[:, :, 2]
    return Truth(
        t_ns=np.arange(n, dtype=np.int64) * 1_000_000,
        R_base_tool=R,
        p_tip_base_m=p,
        rcm_base_m=np.asarray(rcm, float),
        trial=-np.ones(n, np.int32),
        phase=np.zeros(n, np.uint8),
    )
