"""Motion-analysis quantities of a tip path under a fulcrum (pure numpy; base frame, SI units).

The instrument pivots about the trocar's remote centre of motion r: the tip is p = r + L u with
L the insertion depth and u the shaft direction, so every tip path is also a path of (L, u) and
of the roll about the shaft. Speeds and paths here are of samples on a uniform time grid.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt
from scipy.spatial import ConvexHull, QhullError


def lowpass(x: np.ndarray, rate_hz: float, cutoff_hz: float, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth low-pass along axis 0 (forward and backward: twice `order`, no lag)."""
    sos = butter(order, cutoff_hz, fs=rate_hz, output="sos")
    return sosfiltfilt(sos, np.asarray(x, dtype=float), axis=0)


def speed(p_m: np.ndarray, rate_hz: float) -> np.ndarray:
    """Speed (n,) [m/s] of positions (n, 3) [m] by central differences."""
    return np.linalg.norm(np.gradient(p_m, axis=0), axis=1) * rate_hz


def path_length(x: np.ndarray) -> float:
    """Length of a polyline (n, k), or the total variation of a signal (n,), in its unit."""
    x = np.asarray(x, dtype=float)
    d = np.diff(x, axis=0)
    return float(np.sum(np.abs(d)) if x.ndim == 1 else np.sum(np.linalg.norm(d, axis=1)))


def shaft_coordinates(p_tip_m: np.ndarray, rcm_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Insertion depth L (n,) [m] and unit shaft direction u (n, 3) of tips (n, 3) about the RCM (3,)."""
    d = np.asarray(p_tip_m, dtype=float) - np.asarray(rcm_m, dtype=float)
    depth = np.linalg.norm(d, axis=1)
    return depth, d / np.maximum(depth, 1e-12)[:, None]


def elevation_azimuth(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Elevation (the shaft's angle from the downward vertical) and azimuth (about the vertical,
    from base x toward base y, unwrapped) [rad] of shaft directions (n, 3)."""
    elevation = np.arccos(np.clip(-u[:, 2], -1.0, 1.0))
    azimuth = np.unwrap(np.arctan2(u[:, 1], u[:, 0]))
    return elevation, azimuth


def swept_angle(u: np.ndarray) -> float:
    """Total angle [rad] the shaft direction (n, 3) sweeps: the sum of the angles between samples."""
    c = np.clip(np.einsum("ij,ij->i", u[:-1], u[1:]), -1.0, 1.0)
    s = np.linalg.norm(np.cross(u[:-1], u[1:]), axis=1)
    return float(np.sum(np.arctan2(s, c)))


def roll_angle(q_base_tool_xyzw: np.ndarray) -> np.ndarray:
    """Cumulative roll about the shaft (tool z) [rad] (n,) from orientations (n, 4) as (x, y, z, w):
    the twist about tool z of each relative rotation between samples, summed from 0."""
    q = np.asarray(q_base_tool_xyzw, dtype=float)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    a, b = q[:-1], q[1:]
    # relative rotation a^-1 b in tool axes: its z and w parts give the twist about tool z
    w = a[:, 3] * b[:, 3] + np.einsum("ij,ij->i", a[:, :3], b[:, :3])
    z = a[:, 3] * b[:, 2] - b[:, 3] * a[:, 2] - (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    twist = 2.0 * np.arctan2(z, w)
    twist = (twist + np.pi) % (2.0 * np.pi) - np.pi
    return np.concatenate([[0.0], np.cumsum(twist)])


def fulcrum_reference_length(p0_m: np.ndarray, p1_m: np.ndarray, rcm_m: np.ndarray, steps: int = 256) -> float:
    """Tip path length [m] from p0 to p1 of the simplest motion under the fulcrum: the shaft turned
    about the RCM along the great circle from u0 to u1 while the depth changes linearly."""
    (L0, L1), (u0, u1) = shaft_coordinates(np.stack([p0_m, p1_m]), rcm_m)
    angle = np.arctan2(np.linalg.norm(np.cross(u0, u1)), np.clip(u0 @ u1, -1.0, 1.0))
    s = np.linspace(0.0, 1.0, steps + 1)
    L = L0 + (L1 - L0) * s
    # |dp|^2 = dL^2 + (L dtheta)^2 along this path: integrate its length numerically
    integrand = np.hypot(L1 - L0, L * angle)
    return float(np.trapezoid(integrand, s))


def economy(p_m: np.ndarray, rcm_m: np.ndarray) -> tuple[float, float]:
    """(straight-line, fulcrum-aware) economy of motion of a tip path (n, 3): the straight distance
    from its start to its end, and `fulcrum_reference_length` between them, each over the path's
    length. 1 is the most economical; the fulcrum form can exceed 1 for a path more direct than a
    pure pivot-and-insert."""
    length = path_length(p_m)
    if length <= 0.0:
        return float("nan"), float("nan")
    straight = float(np.linalg.norm(p_m[-1] - p_m[0]))
    return straight / length, fulcrum_reference_length(p_m[0], p_m[-1], rcm_m) / length


def working_volume(p_m: np.ndarray) -> float:
    """Volume [m^3] of the convex hull of tip positions (n, 3); 0 for a flat or too small set."""
    if len(p_m) < 4:
        return 0.0
    try:
        return float(ConvexHull(np.asarray(p_m, dtype=float)).volume)
    except QhullError:  # all points on a plane or a line
        return 0.0


def runs_above(mask: np.ndarray) -> list[tuple[int, int]]:
    """[(start, end)) index ranges where a boolean mask (n,) is true."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def movements(
    speed_mps: np.ndarray, rate_hz: float, threshold_mps: float, min_duration_s: float, merge_gap_s: float
) -> list[tuple[int, int]]:
    """Movements of a speed profile (n,): [(start, end)) sample ranges where the speed is at or
    above threshold_mps, runs separated by less than merge_gap_s joined, runs shorter than
    min_duration_s dropped."""
    runs = runs_above(np.asarray(speed_mps) >= threshold_mps)
    merged: list[tuple[int, int]] = []
    for a, b in runs:
        if merged and (a - merged[-1][1]) / rate_hz < merge_gap_s:
            merged[-1] = (merged[-1][0], b)
        else:
            merged.append((a, b))
    return [(a, b) for a, b in merged if (b - a) / rate_hz >= min_duration_s]


def idle_time(speed_mps: np.ndarray, rate_hz: float, threshold_mps: float) -> float:
    """Time [s] the speed profile (n,) spends below threshold_mps."""
    return float(np.count_nonzero(np.asarray(speed_mps) < threshold_mps) / rate_hz)
