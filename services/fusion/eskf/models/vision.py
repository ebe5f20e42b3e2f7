"""A vision frame's two measurements, in camera coordinates: the shaft's tangent planes (the
axis' direction and offset) and the junction ray (the tip, free along the line of sight).
numpy, not compiled: they come at the frame rate. Gating, confirmation and the noise's
adaptation are the filter's (`filter.TrackingFilter.update_vision`)."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.init import E_Z, perp_basis
from services.fusion.eskf.kernels.so3 import skew
from services.fusion.eskf.layout import IP, ITH, N


def tangent_planes(
    R: np.ndarray, p: np.ndarray, n: np.ndarray, A: np.ndarray, cam: np.ndarray, radius_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(H (4, 16), y (4,)) of the two planes through the camera centre tangent to the shaft,
    unit normals n (2, 3) in camera coordinates with n.x = radius_m for every point x on the
    axis: the shaft direction u = R[:, 2] lies in both (n.u = 0), and the tip p, on the axis,
    is radius_m from each (n.(p - cam) = radius_m). A: base -> camera; cam: the camera centre
    [m, base]."""
    nA = n @ A
    H = np.zeros((4, N))
    H[:2, ITH] = -(nA @ R) @ skew(E_Z)
    H[2:, IP] = nA
    y = np.concatenate([-(nA @ R[:, 2]), radius_m - nA @ (p - cam)])
    return H, y


def junction_ray(
    R: np.ndarray, p: np.ndarray, d: np.ndarray, A: np.ndarray, cam: np.ndarray, offset_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(H (2, 16), y (2,), residual (3,)) of the junction ray d (unit, camera coordinates): the
    junction J = p - offset_m u (vision's tip minus the true tip, along the shaft u = R[:, 2])
    lies on the ray, measured across it (the two directions `perp_basis(d)`), free along it.
    The residual is y in camera coordinates (the tip's confirmation compares them)."""
    E = perp_basis(d)
    EA = E @ A
    J = p - offset_m * R[:, 2]
    H = np.zeros((2, N))
    H[:, IP] = EA
    H[:, ITH] = (EA @ R) @ skew(E_Z) * offset_m
    y = -(EA @ (J - cam))
    return H, y, E.T @ y
