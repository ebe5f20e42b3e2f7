"""Building blocks of the bench's commanded trajectories (pure numpy, no I/O).

A `Command` holds raw tip targets p_raw (N, 3) [m, base] and a roll angle about the shaft (N,)
[rad] at the servo rate, with per-sample trial index and phase and a list of trial descriptions.
`Builder` appends segments written as (pitch, yaw, depth, roll) poses about the neutral shaft:
the tip is r + L exp(pitch a_p + yaw a_y) u0, with a_p horizontal (positive pitch tilts the shaft
further from vertical) and a_y = u0 x a_p; moves are minimum-jerk.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from services.bench.robot.operator_style import OperatorStyle
from tiplog.geometry import so3_exp

FREE, PRE, MOVE, POST, HOLD = 0, 1, 2, 3, 4
PHASE_NAMES = {FREE: "free", PRE: "pre", MOVE: "move", POST: "post", HOLD: "hold"}
WINDOW_KEYS = ("pre_start", "pre_end", "move_start", "move_end", "post_start", "post_end")


@dataclass(frozen=True)
class ProtocolContext:
    """Bench geometry and limits the protocols need (SI units, base frame)."""

    r_m: np.ndarray
    R_neutral: np.ndarray
    R_base_camera: np.ndarray
    depth_m: float = 0.140
    rate_hz: float = 1000.0
    tip_speed_max_mps: float = 0.05
    speed_fraction: float = 0.8
    roll_rate_max_radps: float = np.deg2rad(60.0)
    min_move_s: float = 1.5
    working_depth_m: tuple[float, float] = (0.130, 0.150)
    tilt_envelope_rad: float = np.deg2rad(10.0)
    operator: OperatorStyle = OperatorStyle()  # how the teleop operator departs from the drawn path

    @property
    def u0(self) -> np.ndarray:
        return self.R_neutral[:, 2]

    @property
    def a_pitch(self) -> np.ndarray:
        u0 = self.u0
        h = np.array([u0[1], -u0[0], 0.0])  # horizontal, perpendicular to u0
        n = np.linalg.norm(h)
        return h / n if n > 1e-9 else self.R_neutral[:, 1]

    @property
    def a_yaw(self) -> np.ndarray:
        return np.cross(self.u0, self.a_pitch)


@dataclass
class Command:
    """Commanded tip targets p_raw_m (N, 3), roll_rad (N,), trial (N,) int32, phase (N,) uint8."""

    p_raw_m: np.ndarray
    roll_rad: np.ndarray
    trial: np.ndarray
    phase: np.ndarray
    trials: list[dict] = field(default_factory=list)

    def truncate(self, n: int) -> Command:
        """The first n samples; trials that start inside are kept, their windows clipped to n and
        flagged complete=False when cut."""
        keep = []
        for t in self.trials:
            if t["pre_start"] >= n:
                continue
            t = dict(t)
            t["complete"] = t["post_end"] <= n
            for key in WINDOW_KEYS:
                t[key] = min(t[key], n)
            keep.append(t)
        return Command(self.p_raw_m[:n], self.roll_rad[:n], self.trial[:n], self.phase[:n], keep)


def min_jerk(n: int) -> np.ndarray:
    """Minimum-jerk progress s in [0, 1] over n samples (s[0] = 0, s[-1] = 1)."""
    tau = np.linspace(0.0, 1.0, n) if n > 1 else np.ones(1)
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


class Builder:
    """Appends segments of (pitch, yaw, depth, roll) poses or Cartesian targets."""

    def __init__(self, ctx: ProtocolContext) -> None:
        self.ctx = ctx
        self.pose = np.array([0.0, 0.0, ctx.depth_m, 0.0])
        self.p: list[np.ndarray] = []
        self.roll: list[np.ndarray] = []
        self.trial: list[np.ndarray] = []
        self.phase: list[np.ndarray] = []
        self.trials: list[dict] = []
        self.n = 0

    def tip(self, poses: np.ndarray) -> np.ndarray:
        c = self.ctx
        rotvec = poses[:, :1] * c.a_pitch + poses[:, 1:2] * c.a_yaw
        return c.r_m + poses[:, 2:3] * (so3_exp(rotvec) @ c.u0)

    def n_of(self, seconds: float) -> int:
        return max(1, int(round(seconds * self.ctx.rate_hz)))

    def add_cart(self, p: np.ndarray, roll: np.ndarray, phase: int, trial: int = -1) -> tuple[int, int]:
        start = self.n
        self.p.append(np.asarray(p, float))
        self.roll.append(np.asarray(roll, float))
        self.trial.append(np.full(len(p), trial, np.int32))
        self.phase.append(np.full(len(p), phase, np.uint8))
        self.n += len(p)
        return start, self.n

    def add_poses(self, poses: np.ndarray, phase: int, trial: int = -1) -> tuple[int, int]:
        self.pose = poses[-1].copy()
        return self.add_cart(self.tip(poses), poses[:, 3], phase, trial)

    def hold(self, seconds: float, phase: int, trial: int = -1) -> tuple[int, int]:
        return self.add_poses(np.repeat(self.pose[None], self.n_of(seconds), 0), phase, trial)

    def move_time(self, target: np.ndarray, extra_m: float = 0.0) -> float:
        c = self.ctx
        d = target - self.pose
        path_m = max(self.pose[2], target[2]) * np.hypot(d[0], d[1]) + abs(d[2]) + extra_m
        return max(
            c.min_move_s,
            1.875 * path_m / (c.speed_fraction * c.tip_speed_max_mps),
            1.875 * abs(d[3]) / c.roll_rate_max_radps,
        )

    def move(self, target, phase: int, trial: int = -1, seconds: float | None = None) -> tuple[int, int]:
        target = np.asarray(target, float)
        T = seconds if seconds is not None else self.move_time(target)
        s = min_jerk(self.n_of(T) + 1)[1:, None]
        return self.add_poses(self.pose + s * (target - self.pose), phase, trial)

    def record(self, kind: str, axis: str, magnitude: float, unit: str, pre, move, post, **extra) -> None:
        self.trials.append(
            dict(
                index=len(self.trials),
                kind=kind,
                axis=axis,
                magnitude=float(magnitude),
                unit=unit,
                pre_start=pre[0],
                pre_end=pre[1],
                move_start=move[0],
                move_end=move[1],
                post_start=post[0],
                post_end=post[1],
                complete=True,
                **extra,
            )
        )

    def build(self) -> Command:
        cat = np.concatenate
        return Command(cat(self.p), cat(self.roll), cat(self.trial), cat(self.phase), self.trials)


def oscillation(b: Builder, axis: str, x: np.ndarray, trial: int) -> tuple[int, int]:
    """Append offsets x (n,) [m of tip travel, m of depth or rad of roll] about the current pose."""
    poses = np.repeat(b.pose[None], len(x), 0)
    if axis == "pitch" or axis == "tilt":
        poses[:, 0] += x / b.pose[2]
    elif axis == "depth":
        poses[:, 2] += x
    else:
        poses[:, 3] += x
    out = b.add_poses(poses, MOVE, trial)
    b.pose = poses[-1].copy()
    return out


def taper(n: int, n_ramp: int) -> np.ndarray:
    w = np.ones(n)
    ramp = min_jerk(n_ramp)
    w[:n_ramp] = ramp
    w[n - n_ramp :] = np.minimum(w[n - n_ramp :], ramp[::-1])
    return w


def concat(commands: list[Command], gap_samples: int = 0) -> Command:
    """Chain commands (each starts and ends at neutral at rest); trial indices renumbered."""
    ps, rolls, trials, phases, infos, n, k = [], [], [], [], [], 0, 0
    for c in commands:
        tr = c.trial.copy()
        tr[tr >= 0] += k
        ps.append(c.p_raw_m)
        rolls.append(c.roll_rad)
        trials.append(tr)
        phases.append(c.phase)
        for info in c.trials:
            d = dict(info)
            d["index"] += k
            for key in WINDOW_KEYS:
                d[key] += n
            infos.append(d)
        k += len(c.trials)
        n += len(c.p_raw_m)
        if gap_samples:
            ps.append(np.repeat(c.p_raw_m[-1:], gap_samples, 0))
            rolls.append(np.repeat(c.roll_rad[-1:], gap_samples))
            trials.append(np.full(gap_samples, -1, np.int32))
            phases.append(np.full(gap_samples, FREE, np.uint8))
            n += gap_samples
    cat = np.concatenate
    return Command(cat(ps), cat(rolls), cat(trials), cat(phases), infos)
