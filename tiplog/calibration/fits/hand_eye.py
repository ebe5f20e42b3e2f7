"""Hand-eye calibration of a fixed camera: AX = XB in closed form, refined by least squares.

The robot holds a marker (fixed on the tool, pose Y = T_tool_marker, unknown) in front of a
camera fixed in the base (X = T_base_camera, unknown). Pose i gives the robot's B_i =
T_base_tool and the detected C_i = T_camera_marker, with B_i Y = X C_i. For two poses,
A = B_j B_i^-1 and B = C_j C_i^-1 satisfy A X = X B. The closed form is Park and Martin's
(1994): R_X = (M^T M)^-1/2 M^T with M = sum beta alpha^T over the motions' rotation vectors,
then t_X by linear least squares; Y is the mean of B_i^-1 X C_i. Both are then refined over
all poses by nonlinear least squares on the marker's predicted pose in the camera (position
in metres, rotation in radians scaled by `rot_scale_m`). Held-out error: per held-out pose,
the distance and angle between the predicted and detected marker pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from tiplog.calibration.fits import require
from tiplog.calibration.fits.windows import mean_rotation
from tiplog.geometry import so3_exp, so3_log

FIT = "hand-eye"


def _inv(T: np.ndarray) -> np.ndarray:
    R, t = T[..., :3, :3], T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def _T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


@dataclass(frozen=True)
class HandEyeResult:
    T_base_camera: np.ndarray  # X (4, 4)
    T_tool_marker: np.ndarray  # Y (4, 4)
    closed_form_T_base_camera: np.ndarray  # before refinement
    fit_mean_mm: float
    fit_mean_deg: float
    heldout_mean_mm: float  # nan without held-out poses
    heldout_mean_deg: float
    poses: int
    heldout_poses: int


def closed_form(B: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(X, Y) from poses B (n, 4, 4) = T_base_tool and C (n, 4, 4) = T_camera_marker."""
    n = len(B)
    i, j = np.triu_indices(n, 1)
    A = B[j] @ _inv(B[i])
    Bm = C[j] @ _inv(C[i])
    alpha = so3_log(A[:, :3, :3])
    beta = so3_log(Bm[:, :3, :3])
    big = np.linalg.norm(alpha, axis=1) > np.radians(2.0)
    require(np.sum(big) >= 2, FIT, "needs motions of more than 2 deg between poses")
    alpha, beta = alpha[big], beta[big]
    axes = alpha / np.linalg.norm(alpha, axis=1, keepdims=True)
    s = np.linalg.svd(axes, compute_uv=False)
    require(
        s[1] / s[0] > 0.1,
        FIT,
        "all motions rotate about parallel axes: rotate the tool about at least two different axes",
    )
    # alpha = R_X beta: Park and Martin's (M^T M)^-1/2 M^T with M = sum beta alpha^T, written as
    # the SVD (Kabsch) solution, which also holds when the motions span only two axes
    M = beta.T @ alpha
    U, _, Vt = np.linalg.svd(M)
    R_X = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    RA, tA, tB = A[big][:, :3, :3], A[big][:, :3, 3], Bm[big][:, :3, 3]
    lhs = (RA - np.eye(3)).reshape(-1, 3)
    rhs = (tB @ R_X.T - tA).reshape(-1)
    t_X = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    X = _T(R_X, t_X)
    Ys = _inv(B) @ X @ C
    Y = _T(mean_rotation(Ys[:, :3, :3]), Ys[:, :3, 3].mean(0))
    return X, Y


def _errors(X: np.ndarray, Y: np.ndarray, B: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pose: distance [m] and angle [rad] between predicted X^-1 B Y and detected C."""
    P = _inv(X) @ B @ Y
    d = np.linalg.norm(P[:, :3, 3] - C[:, :3, 3], axis=1)
    a = np.linalg.norm(so3_log(np.einsum("nji,njk->nik", P[:, :3, :3], C[:, :3, :3])), axis=1)
    return d, a


def refine(
    X: np.ndarray, Y: np.ndarray, B: np.ndarray, C: np.ndarray, rot_scale_m: float = 0.18
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares refinement of (X, Y) over all poses."""

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Xi = _T(X[:3, :3] @ so3_exp(x[:3]), X[:3, 3] + x[3:6])
        Yi = _T(Y[:3, :3] @ so3_exp(x[6:9]), Y[:3, 3] + x[9:12])
        return Xi, Yi

    def resid(x: np.ndarray) -> np.ndarray:
        Xi, Yi = unpack(x)
        P = _inv(Xi) @ B @ Yi
        dp = P[:, :3, 3] - C[:, :3, 3]
        dr = so3_log(np.einsum("nji,njk->nik", C[:, :3, :3], P[:, :3, :3])) * rot_scale_m
        return np.concatenate([dp, dr], 1).ravel()

    sol = least_squares(resid, np.zeros(12), loss="soft_l1", f_scale=0.01)
    return unpack(sol.x)


def fit_hand_eye(
    T_base_tool: np.ndarray, T_camera_marker: np.ndarray, heldout: int = 0, rot_scale_m: float = 0.18
) -> HandEyeResult:
    """X and Y from n poses (n, 4, 4) each; the last `heldout` poses are kept out of the fit
    and scored. Needs at least 3 fitting poses with rotations about two or more axes."""
    B = np.asarray(T_base_tool, float)
    C = np.asarray(T_camera_marker, float)
    require(B.shape == C.shape and B.ndim == 3 and B.shape[1:] == (4, 4), FIT, "needs matching (n, 4, 4) pose lists")
    require(heldout >= 0, FIT, f"the number of held-out poses must be 0 or more (got {heldout})")
    n_fit = len(B) - heldout
    require(
        n_fit >= 3,
        FIT,
        f"needs at least 3 poses to fit; holding out the last {heldout} of {len(B)} leaves {max(n_fit, 0)}"
        if heldout
        else f"needs at least 3 poses to fit (got {len(B)})",
    )
    X0, Y0 = closed_form(B[:n_fit], C[:n_fit])
    X, Y = refine(X0, Y0, B[:n_fit], C[:n_fit], rot_scale_m)
    d, a = _errors(X, Y, B[:n_fit], C[:n_fit])
    if heldout:
        dh, ah = _errors(X, Y, B[n_fit:], C[n_fit:])
        hm, hd = float(dh.mean() * 1e3), float(np.degrees(ah.mean()))
    else:
        hm = hd = float("nan")
    return HandEyeResult(X, Y, X0, float(d.mean() * 1e3), float(np.degrees(a.mean())), hm, hd, n_fit, heldout)
