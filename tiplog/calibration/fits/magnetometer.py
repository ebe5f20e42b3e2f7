"""The magnetometer study that motivates the design (paper, Preliminary Study): what a
nine-axis estimate would do on the bench, from the accelerometer and magnetometer alone.

- TRIAD: the body-frame triad of gravity (accelerometer at rest) and the field; the relative
  rotation between two rests is T_post^T T_pre's rotation angle (invariant to the unknown
  reference frame), compared with the robot's relative rotation angle.
- The field's angle to gravity per rest: constant for an undisturbed field; its change
  between the two rests of a trial shows the pose-dependent disturbance.
- Nine-axis heading drift within a static hold: the heading of the field's horizontal
  component (gravity from the accelerometer) in the hold's first and last seconds.
Inputs are per-rest means in the imu frame (accelerometer [m/s^2], magnetometer [uT]).
"""

from __future__ import annotations

import numpy as np

from tiplog.geometry import rotation_angle


def triad(a: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Body-frame triads (..., 3, 3), columns: gravity-up direction, a x m, and their cross."""
    a = np.asarray(a, float)
    m = np.asarray(m, float)
    t1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
    t2 = np.cross(a, m)
    t2 /= np.linalg.norm(t2, axis=-1, keepdims=True)
    return np.stack([t1, t2, np.cross(t1, t2)], -1)


def triad_rotation_angle_deg(
    a_pre: np.ndarray, m_pre: np.ndarray, a_post: np.ndarray, m_post: np.ndarray
) -> np.ndarray:
    """Rotation angle [deg] (n,) between two rests from accelerometer and magnetometer alone."""
    Tp, Tq = triad(a_pre, m_pre), triad(a_post, m_post)
    return np.degrees(rotation_angle(np.einsum("nji,njk->nik", Tq, Tp)))


def field_gravity_angle_deg(a: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Angle [deg] between the measured field and gravity (down: minus the accelerometer's
    specific force at rest); 90 deg minus the field's inclination when undisturbed."""
    a = -np.asarray(a, float)
    m = np.asarray(m, float)
    c = np.sum(a * m, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(m, axis=-1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def heading_deg(a: np.ndarray, m: np.ndarray, forward_imu: np.ndarray | None = None) -> np.ndarray:
    """Heading [deg] of the imu's `forward_imu` axis (default x) about gravity, measured from
    the field's horizontal component (..,)."""
    a = np.asarray(a, float)
    m = np.asarray(m, float)
    up = a / np.linalg.norm(a, axis=-1, keepdims=True)
    east = np.cross(m, up)
    east /= np.linalg.norm(east, axis=-1, keepdims=True)
    north = np.cross(up, east)
    f = np.array([1.0, 0.0, 0.0]) if forward_imu is None else np.asarray(forward_imu, float)
    return np.degrees(np.arctan2(np.sum(east * f, -1), np.sum(north * f, -1)))


def hold_drift_deg(
    a_first: np.ndarray, m_first: np.ndarray, a_last: np.ndarray, m_last: np.ndarray
) -> tuple[float, float]:
    """(nine-axis heading drift, accelerometer tilt drift) [deg] within a hold, from the mean
    accelerometer and magnetometer over its first and last seconds."""
    dh = (heading_deg(a_last, m_last) - heading_deg(a_first, m_first) + 180.0) % 360.0 - 180.0
    c = a_first @ a_last / np.linalg.norm(a_first) / np.linalg.norm(a_last)
    return float(abs(dh)), float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
