"""The camera's pose in the base, refined on the shaft the camera sees in the fit-only block.

The marker hand-eye calibration (`hand_eye.py`) leaves the camera pose X = T_base_camera off
by a few tenths of a degree and about a millimetre (the paper: 2.35 mm / 0.74 deg per held-out
pose over 30 poses). Through the camera's distance to the tip that is a millimetre or more of
tip error in every vision update, more than the fusion's whole error budget. The fit-only block
holds the robot still at ten poses while vision watches the shaft, so it can re-fit X.

Per accepted frame at a static pose, with the robot's shaft axis {p + s u} in the base frame:
- each tangent plane of the silhouette (unit normal n through the camera centre, camera
  frame) is at the shaft radius from the axis: n . R^T (x - c) = rho at the tip x = p and at
  x = p - 100 mm u (two residuals per plane);
- the junction, at p - L_j u, lies on the junction's ray d: the point's distance from the ray
  in the two directions across it (two residuals).
X's error along the shaft and the junction's offset along it move the junction the same way,
so the junction-to-tip distance L_j is fitted with X (seven unknowns): the block's L_j goes
with the block's X. Gauss-Newton from the starting constants; each group (planes, junction)
is weighted by its own robust SD and frames beyond four SDs are dropped (wrong lines, gross
junction errors); a weak prior on the change (1 deg, 5 mm, 5 mm) keeps what the poses leave
undetermined where it started.

The refit X is not the camera's true pose: it also takes up the vision's pose-locked errors
over the block's poses. It is the pose that makes vision agree with the robot in the working
region, which is what the fusion needs. Held out: leave one pose out, the RMS of its frames'
residuals under the fit of the other poses (planes and junction, mm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tiplog.calibration.fits import require
from tiplog.calibration.fits.rcm import direction_spread_deg
from tiplog.calibration.fits.windows import kfold
from tiplog.geometry import rotation_angle, skew, so3_exp, so3_log

FIT = "camera"
BEHIND_TIP_M = 0.10  # second point of the axis for the tangent planes
PRIOR = (np.radians(1.0), 5e-3, 5e-3)  # SD of the change: rotation [rad], position [m], L_j [m]
ITERATIONS = 8
OUTLIER_SD = 4.0


@dataclass(frozen=True)
class CameraFrames:
    """Accepted vision frames at static poses, with the robot's pose at each (base frame)."""

    pose: np.ndarray  # (n,) int: which static pose
    R_base_tool: np.ndarray  # (n, 3, 3)
    p_tip_base_m: np.ndarray  # (n, 3)
    n_left: np.ndarray  # (n, 3) camera frame
    n_right: np.ndarray  # (n, 3)
    junction_ray: np.ndarray  # (n, 3) unit, camera frame
    junction_visible: np.ndarray  # (n,) bool


@dataclass(frozen=True)
class CameraResult:
    T_base_camera: np.ndarray  # (4, 4)
    junction_proximal_m: float  # junction-to-tip distance that goes with this pose
    rotation_change_deg: float  # from the starting pose
    position_change_mm: float
    residual_mm: dict[str, float]  # RMS over kept frames: planes, junction
    prior_residual_mm: dict[str, float]  # the same under the starting constants
    heldout_mm: dict[str, float]  # leave one pose out
    sd: dict[str, list[float]]  # posterior SDs: rotation [deg] (3), position [mm] (3), L_j [mm]
    frames: int
    dropped: int
    poses: int


def _perp(d: np.ndarray) -> np.ndarray:
    """(n, 3) unit rays -> (n, 2, 3) two unit vectors across each."""
    a = np.where(np.abs(d[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(d, e1)], 1)


def _residuals(
    f: CameraFrames, R: np.ndarray, c: np.ndarray, L_j: float, rho: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Plane residuals (n, 4) and junction residuals (m, 2) [m] with their Jacobians (n, 4, 7),
    (m, 2, 7) in (rotation of X in the base frame, X's position, L_j)."""
    u = f.R_base_tool[:, :, 2]
    m = np.stack([f.n_left, f.n_right], 1) @ R.T  # base-frame normals (n, 2, 3)
    x = np.stack([f.p_tip_base_m, f.p_tip_base_m - BEHIND_TIP_M * u], 1) - c  # (n, 2, 3)
    ep = np.einsum("nij,nkj->nik", m, x).reshape(-1, 4) - rho
    Jp = np.zeros((len(u), 2, 2, 7))
    Jp[..., :3] = -np.cross(x[:, None, :, :], m[:, :, None, :])
    Jp[..., 3:6] = -m[:, :, None, :]
    jv = f.junction_visible
    xj = f.p_tip_base_m[jv] - L_j * u[jv] - c
    ER = _perp(f.junction_ray[jv]) @ R.T  # rows: the across-ray directions in the base frame
    ej = np.einsum("nij,nj->ni", ER, xj)
    Jj = np.concatenate([ER @ skew(xj), -ER, -np.einsum("nij,nj->ni", ER, u[jv])[..., None]], -1)
    return ep, Jp.reshape(-1, 4, 7), ej, Jj


def _solve(f: CameraFrames, T0: np.ndarray, L0: float, rho: float) -> tuple[np.ndarray, np.ndarray, float, dict]:
    R0, c0 = T0[:3, :3], T0[:3, 3]
    R, c, L = R0.copy(), c0.copy(), float(L0)
    wp = np.ones((len(f.pose), 4))
    wj = np.ones((int(f.junction_visible.sum()), 2))
    prior_w = 1.0 / np.repeat(np.asarray(PRIOR), [3, 3, 1])
    for it in range(ITERATIONS):
        ep, Jp, ej, Jj = _residuals(f, R, c, L, rho)
        if it:  # robust scale of each group from the current residuals; outliers get weight 0
            wp, wj = _robust_weights(ep), _robust_weights(ej)
        dev = np.concatenate([so3_log(R @ R0.T), c - c0, [L - L0]])
        A = np.concatenate([(Jp * wp[..., None]).reshape(-1, 7), (Jj * wj[..., None]).reshape(-1, 7), np.diag(prior_w)])
        b = np.concatenate([(ep * wp).ravel(), (ej * wj).ravel(), dev * prior_w])
        step = np.linalg.lstsq(A, -b, rcond=None)[0]
        R = so3_exp(step[:3]) @ R
        c = c + step[3:6]
        L += float(step[6])
    ep, _, ej, _ = _residuals(f, R, c, L, rho)
    cov = np.linalg.pinv(A.T @ A)
    stats = {
        "ep": ep,
        "ej": ej,
        "kept_p": wp > 0,
        "kept_j": wj > 0,
        "sd": np.sqrt(np.diag(cov)),
    }
    return R, c, L, stats


def residuals_mm(
    frames: CameraFrames, T_base_camera: np.ndarray, junction_proximal_m: float, shaft_radius_m: float
) -> dict[str, float]:
    """RMS plane and junction residuals [mm] of `frames` under the given constants (frames
    beyond four robust SDs left out)."""
    T = np.asarray(T_base_camera, float)
    ep, _, ej, _ = _residuals(frames, T[:3, :3], T[:3, 3], junction_proximal_m, shaft_radius_m)
    return {"planes": _robust_rms_mm(ep.ravel()), "junction": _robust_rms_mm(ej.ravel())}


def _rms_mm(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)) * 1e3) if x.size else float("nan")


def _subset(f: CameraFrames, keep: np.ndarray) -> CameraFrames:
    return CameraFrames(*(getattr(f, k)[keep] for k in CameraFrames.__dataclass_fields__))


def fit_camera(
    frames: CameraFrames, T_base_camera: np.ndarray, junction_proximal_m: float, shaft_radius_m: float
) -> CameraResult:
    """Refine T_base_camera (and the junction-to-tip distance that goes with it) from
    accepted frames at k >= 3 static poses with different shaft directions."""
    poses = np.unique(frames.pose)
    per_pose = np.array([np.sum(frames.pose == k) for k in poses])
    require(
        np.sum(per_pose >= 3) >= 3,
        FIT,
        f"needs at least 3 static poses with 3+ accepted vision frames (got {int(np.sum(per_pose >= 3))})",
    )
    require(
        int(frames.junction_visible.sum()) >= 3,
        FIT,
        f"needs frames showing the shaft junction (got {int(frames.junction_visible.sum())})",
    )
    spread = direction_spread_deg(frames.R_base_tool[:, :, 2])
    require(spread >= 1.0, FIT, f"the shaft directions span only {spread:.2f} deg (need 1 deg)")
    T0 = np.asarray(T_base_camera, float)
    R, c, L, st = _solve(frames, T0, junction_proximal_m, shaft_radius_m)
    held_p, held_j = [], []
    for tr, te in kfold(len(poses), len(poses)):
        ftr = _subset(frames, np.isin(frames.pose, poses[tr]))
        fte = _subset(frames, np.isin(frames.pose, poses[te]))
        Ri, ci, Li, _ = _solve(ftr, T0, junction_proximal_m, shaft_radius_m)
        ep, _, ej, _ = _residuals(fte, Ri, ci, Li, shaft_radius_m)
        held_p.append(ep.ravel())
        held_j.append(ej.ravel())
    T = T0.copy()
    T[:3, :3], T[:3, 3] = R, c
    sd = st["sd"]
    return CameraResult(
        T_base_camera=T,
        junction_proximal_m=L,
        rotation_change_deg=float(np.degrees(rotation_angle(R @ T0[:3, :3].T))),
        position_change_mm=float(np.linalg.norm(c - T0[:3, 3]) * 1e3),
        residual_mm={"planes": _rms_mm(st["ep"][st["kept_p"]]), "junction": _rms_mm(st["ej"][st["kept_j"]])},
        prior_residual_mm=residuals_mm(frames, T0, junction_proximal_m, shaft_radius_m),
        heldout_mm={
            "planes": _robust_rms_mm(np.concatenate(held_p)),
            "junction": _robust_rms_mm(np.concatenate(held_j)),
        },
        sd={
            "rotation_deg": [float(x) for x in np.degrees(sd[:3])],
            "position_mm": [float(x) for x in sd[3:6] * 1e3],
            "junction_mm": [float(sd[6] * 1e3)],
        },
        frames=len(frames.pose),
        dropped=int((~st["kept_p"]).any(1).sum()),
        poses=len(poses),
    )


def _robust_weights(x: np.ndarray) -> np.ndarray:
    """1 / robust SD (1.4826 x median |x|) for residuals within OUTLIER_SD of it, else 0."""
    if not x.size:
        return np.ones_like(x)
    sd = 1.4826 * np.median(np.abs(x))
    return (np.abs(x) < OUTLIER_SD * sd) / sd


def _robust_rms_mm(x: np.ndarray) -> float:
    """RMS [mm] of the residuals within four robust SDs (wrong lines and gross junction
    errors excluded, as in the fit)."""
    return _rms_mm(x[_robust_weights(x) > 0])
