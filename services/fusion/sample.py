"""`StateSample`: one published filter state, and how it is made from a `State`."""

from __future__ import annotations

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


def make_sample(s: State, rcm_base_m: np.ndarray, neutral_u: np.ndarray, lock_ns: int) -> StateSample:
    f = kernels.sample_fields(s.R, s.p, s.P, rcm_base_m, neutral_u).tolist()
    return StateSample(
        stamp_ns=int(s.t_ns),
        p_tip_base_m=s.p.copy(),
        v_tip_base_mps=s.v.copy(),
        q_base_tool=np.array(f[0:4]),
        u_base=s.R[:, 2].copy(),
        depth_m=f[4],
        tilt_deg=f[5],
        roll_deg=f[6],
        gyro_bias_radps=s.bg.copy(),
        accel_bias_mps2=s.ba.copy(),
        tof_offset_m=float(s.brho),
        tip_sigma_m=np.array(f[7:10]),
        attitude_sigma_deg=f[10],
        vision_locked=(s.t_ns - s.last_vision_ns) <= lock_ns,
        last_vision_stamp_ns=int(max(s.last_vision_ns, 0)),
    )
