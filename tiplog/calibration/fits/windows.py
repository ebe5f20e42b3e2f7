"""Stationary windows of a robot reference and per-window sensor means.

A window is a stretch where the robot's tool is at rest (tip speed and angular rate below
thresholds) for at least `min_s`, trimmed at both ends. Sensor samples are attributed to a
window by their arrival stamp minus the stream's latency, so a few ms of latency error only
moves the window edges, which the trim absorbs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tiplog.geometry import so3_exp, so3_log


@dataclass(frozen=True)
class StaticWindows:
    """(k,) windows [t0_ns, t1_ns) with the robot's mean pose in each."""

    t0_ns: np.ndarray
    t1_ns: np.ndarray
    R_base_tool: np.ndarray  # (k, 3, 3)
    p_tip_base_m: np.ndarray  # (k, 3)

    def __len__(self) -> int:
        return len(self.t0_ns)

    def subset(self, idx: np.ndarray) -> StaticWindows:
        return StaticWindows(self.t0_ns[idx], self.t1_ns[idx], self.R_base_tool[idx], self.p_tip_base_m[idx])


def mean_rotation(R: np.ndarray) -> np.ndarray:
    """Chordal mean of rotations (n, 3, 3) -> (3, 3)."""
    U, _, Vt = np.linalg.svd(R.sum(0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def robot_rates(t_ns: np.ndarray, R: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tip speed [m/s] and angular rate [rad/s] (n,) by central differences."""
    n = len(t_ns)
    v = np.zeros(n)
    w = np.zeros(n)
    if n < 3:
        return v, w
    dt = (t_ns[2:] - t_ns[:-2]) * 1e-9
    v[1:-1] = np.linalg.norm(p[2:] - p[:-2], axis=1) / dt
    w[1:-1] = np.linalg.norm(so3_log(np.einsum("nji,njk->nik", R[:-2], R[2:])), axis=1) / dt
    v[0], v[-1], w[0], w[-1] = v[1], v[-2], w[1], w[-2]
    return v, w


def static_windows(
    t_ns: np.ndarray,
    R_base_tool: np.ndarray,
    p_tip_base_m: np.ndarray,
    min_s: float = 1.5,
    trim_s: float = 0.3,
    max_speed_mps: float = 2e-4,
    max_rate_radps: float = np.radians(0.05),
) -> StaticWindows:
    """Windows where the robot rests at least min_s (after trimming trim_s at each end)."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    v, w = robot_rates(t_ns, R_base_tool, p_tip_base_m)
    still = (v < max_speed_mps) & (w < max_rate_radps)
    edges = np.diff(np.concatenate([[0], still.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    t0, t1, Rs, ps = [], [], [], []
    trim = int(trim_s * 1e9)
    for a, b in zip(starts, ends, strict=True):
        ta, tb = int(t_ns[a]) + trim, int(t_ns[b - 1]) - trim
        if tb - ta < min_s * 1e9:
            continue
        sel = (t_ns >= ta) & (t_ns < tb)
        t0.append(ta)
        t1.append(tb)
        Rs.append(mean_rotation(R_base_tool[sel]))
        ps.append(p_tip_base_m[sel].mean(0))
    return StaticWindows(
        np.asarray(t0, dtype=np.int64),
        np.asarray(t1, dtype=np.int64),
        np.asarray(Rs).reshape(-1, 3, 3),
        np.asarray(ps).reshape(-1, 3),
    )


def window_samples(
    win: StaticWindows, t_ns: np.ndarray, latency_ms: float = 0.0, valid: np.ndarray | None = None
) -> list[np.ndarray]:
    """Indices of the samples (arrival stamps t_ns, shifted back by latency_ms) in each window."""
    t = np.asarray(t_ns, dtype=np.int64) - int(round(latency_ms * 1e6))
    ok = np.ones(len(t), bool) if valid is None else np.asarray(valid, bool)
    out = []
    for a, b in zip(win.t0_ns, win.t1_ns, strict=True):
        i0, i1 = np.searchsorted(t, [a, b])
        idx = np.arange(i0, i1)
        out.append(idx[ok[idx]])
    return out


def interp_pose(
    t_query_ns: np.ndarray, t_ns: np.ndarray, R: np.ndarray, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Robot pose at query times [ns] (linear in position, geodesic in rotation), clamped."""
    tq = np.asarray(t_query_ns, dtype=float)
    t = np.asarray(t_ns, dtype=float)
    i = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, len(t) - 2)
    a = np.clip((tq - t[i]) / (t[i + 1] - t[i]), 0.0, 1.0)
    rel = so3_log(np.einsum("nji,njk->nik", R[i], R[i + 1]))
    Rq = R[i] @ so3_exp(a[:, None] * rel)
    pq = p[i] + a[:, None] * (p[i + 1] - p[i])
    return Rq, pq


def kfold(n: int, k: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Interleaved k-fold split of n items: [(train idx, held-out idx)]; leave-one-out if k >= n."""
    k = min(k, n)
    idx = np.arange(n)
    return [(idx[idx % k != f], idx[idx % k == f]) for f in range(k)]
