"""Initial orientation of the tool from a shaft direction and the accelerometer's gravity, and
the line geometry the filter's vision updates share."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.kernels.so3 import cross

E_Z = np.array([0.0, 0.0, 1.0])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def initial_rotation(u_base: np.ndarray, f_imu: np.ndarray | None, R_tool_imu: np.ndarray) -> np.ndarray:
    """R_base_tool with R e_z = u_base (unit shaft direction) and the roll about the shaft
    that puts the measured specific force f_imu [m/s^2] (IMU frame, at rest: minus gravity)
    closest to base +z; roll 0 (tool x horizontal) without a usable accelerometer sample."""
    u = _unit(np.asarray(u_base, float))
    up_base = np.array([0.0, 0.0, 1.0])
    w = up_base - (up_base @ u) * u
    if np.linalg.norm(w) < 1e-6:  # vertical shaft: any roll
        w = np.array([1.0, 0.0, 0.0]) - u[0] * u
    w = _unit(w)
    up_tool = None
    if f_imu is not None and np.linalg.norm(f_imu) > 1.0:
        up_tool = R_tool_imu @ _unit(np.asarray(f_imu, float))
        wt = up_tool - (up_tool @ E_Z) * E_Z
        if np.linalg.norm(wt) < 1e-6:
            up_tool = None
    if up_tool is None:
        wt = np.array([1.0, 0.0, 0.0])
    wt = _unit(wt)
    base = np.stack([u, w, np.cross(u, w)], 1)
    tool = np.stack([E_Z, wt, np.cross(E_Z, wt)], 1)
    return base @ tool.T


def shaft_from_tilt(f_imu: np.ndarray, R_tool_imu: np.ndarray, heading_base: np.ndarray) -> np.ndarray:
    """Unit shaft direction with the inclination the accelerometer gives and the azimuth of
    `heading_base` (used without vision, where nothing observes heading)."""
    up_tool = R_tool_imu @ _unit(np.asarray(f_imu, float))
    uz = float(np.clip(up_tool @ E_Z, -1.0, 1.0))
    h = np.asarray(heading_base, float)[:2]
    h = h / (np.linalg.norm(h) or 1.0)
    s = np.sqrt(max(0.0, 1.0 - uz * uz))
    return np.array([s * h[0], s * h[1], uz])


def perp_basis(d: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal rows perpendicular to unit d."""
    a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = cross(d, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, cross(d, e1)])


def closest_params(p0: np.ndarray, u: np.ndarray, d: np.ndarray) -> tuple[float, float]:
    """(s, t) minimising |p0 + s u - t d| for unit u, d."""
    du = float(d @ u)
    dp = float(d @ p0)
    up = float(u @ p0)
    den = 1.0 - du * du
    if den < 1e-9:
        return 0.0, dp
    s = (du * dp - up) / den
    return s, dp + s * du
