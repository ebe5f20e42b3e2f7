"""`StateSample`: one published filter state, and how it is made from a `State`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.fusion import kernels
from services.fusion.filter import State


@dataclass(slots=True)
class StateSample:
    """The filter's state at one gyro sample time (host clock, latency-corrected), base frame."""

    stamp_ns: int
    p_tip_base_m: np.ndarray  # (3,)
    v_tip_base_mps: np.ndarray  # (3,)
    q_base_tool: np.ndarray  # (4,) w, x, y, z (Hamilton)
    u_base: np.ndarray  # (3,) shaft direction, distal
    depth_m: float  # insertion depth L along u from the RCM
    tilt_deg: float  # shaft angle from the neutral direction (the first initialised one)
    roll_deg: float  # tool x about the shaft, from the horizontal
    gyro_bias_radps: np.ndarray  # (3,) IMU frame
    accel_bias_mps2: np.ndarray  # (3,) IMU frame
    tof_offset_m: float  # b_rho
    tip_sigma_m: np.ndarray  # (3,) 1-sigma along base x, y, z
    attitude_sigma_deg: float  # sqrt of the attitude covariance's largest eigenvalue bound (trace)
    vision_locked: bool
    last_vision_stamp_ns: int


def quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion (w, x, y, z), w >= 0 (Shepperd, scalar)."""
    m00, m11, m22 = R[0, 0], R[1, 1], R[2, 2]
    tr = m00 + m11 + m22
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = (0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s)
    elif m00 > m11 and m00 > m22:
        s = math.sqrt(1.0 + m00 - m11 - m22) * 2
        q = ((R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s)
    elif m11 > m22:
        s = math.sqrt(1.0 + m11 - m00 - m22) * 2
        q = ((R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s)
    else:
        s = math.sqrt(1.0 + m22 - m00 - m11) * 2
        q = ((R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s)
    out = np.array(q)
    out /= np.linalg.norm(out)
    return -out if out[0] < 0 else out


def make_sample(s: State, rcm_base_m: np.ndarray, neutral_u: np.ndarray, lock_ns: int) -> StateSample:
    f = kernels.sample_fields(s.R, s.p, rcm_base_m, neutral_u)
    d = np.diag(s.P)
    return StateSample(
        stamp_ns=int(s.t_ns),
        p_tip_base_m=s.p.copy(),
        v_tip_base_mps=s.v.copy(),
        q_base_tool=f[0:4],
        u_base=s.R[:, 2].copy(),
        depth_m=float(f[4]),
        tilt_deg=float(f[5]),
        roll_deg=float(f[6]),
        gyro_bias_radps=s.bg.copy(),
        accel_bias_mps2=s.ba.copy(),
        tof_offset_m=float(s.brho),
        tip_sigma_m=np.sqrt(np.maximum(d[0:3], 0.0)),
        attitude_sigma_deg=math.degrees(math.sqrt(max(float(d[6] + d[7] + d[8]), 0.0))),
        vision_locked=(s.t_ns - s.last_vision_ns) <= lock_ns,
        last_vision_stamp_ns=int(max(s.last_vision_ns, 0)),
    )
