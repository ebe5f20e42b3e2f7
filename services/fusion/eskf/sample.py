"""`StateSample`: one published filter state, and how it is made from a `State`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.fusion.eskf.filter import State
from services.fusion.eskf.kernels.sample import sample_row


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
    return _sample(s, sample_row(s.R, s.p, s.v, s.P, s.bg, s.ba, rcm_base_m, neutral_u, False), lock_ns)


def finite_sample(s: State, rcm_base_m: np.ndarray, neutral_u: np.ndarray, lock_ns: int) -> StateSample | None:
    """`make_sample`, or None for a state that is not finite (`State.finite`): one compiled call."""
    row = sample_row(s.R, s.p, s.v, s.P, s.bg, s.ba, rcm_base_m, neutral_u, True)
    return _sample(s, row, lock_ns) if len(row) else None


def _sample(s: State, row: np.ndarray, lock_ns: int) -> StateSample:
    # the arrays are views of the row, which is made for this sample and shared with nothing
    depth, tilt, roll, att = row[22:26].tolist()
    return StateSample(
        int(s.t_ns),
        row[0:3],
        row[3:6],
        row[6:10],
        row[10:13],
        depth,
        tilt,
        roll,
        row[13:16],
        row[16:19],
        float(s.brho),
        row[19:22],
        att,
        (s.t_ns - s.last_vision_ns) <= lock_ns,
        int(max(s.last_vision_ns, 0)),
    )
