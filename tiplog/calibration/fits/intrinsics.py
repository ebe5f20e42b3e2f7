"""Camera intrinsics and distortion (OpenCV plumb_bob: k1 k2 p1 p2 k3) from chessboard views.

Corners are found with OpenCV and refined to sub-pixel; `cv2.calibrateCamera` fits on all
views but the held-out ones, which are then scored by their reprojection RMS [px] after
solving only their pose (solvePnP) with the fitted intrinsics. Views that do not show the
whole board are skipped; too few views, or boards that are all seen face-on (focal length
and distance are then confounded), are refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tiplog.calibration.fits import require

FIT = "intrinsics"


@dataclass(frozen=True)
class IntrinsicsResult:
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float]
    width: int
    height: int
    fit_rms_px: float
    heldout_rms_px: float  # nan without held-out views
    views: int
    heldout_views: int
    tilt_spread_deg: float

    def as_dict(self) -> dict:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "dist": list(self.dist)}


def board_points(cols: int, rows: int, square_m: float) -> np.ndarray:
    """Inner corners of a cols x rows board in its own plane (z = 0), (cols*rows, 3) [m]."""
    g = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(np.float32)
    return np.concatenate([g * square_m, np.zeros((len(g), 1), np.float32)], 1)


def find_corners(gray: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """Sub-pixel inner corners (cols*rows, 2) of an 8-bit grey image, or None."""
    ok, c = cv2.findChessboardCorners(gray, (cols, rows), cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    c = cv2.cornerSubPix(gray, c, (5, 5), (-1, -1), crit)
    return c.reshape(-1, 2)


def fit_intrinsics(
    corners: list[np.ndarray], image_size: tuple[int, int], cols: int, rows: int, square_m: float, heldout: int = 0
) -> IntrinsicsResult:
    """From per-view corners (cols*rows, 2) [px] of an image of size (width, height); the
    last `heldout` views are scored, not fitted. Needs 5+ fitting views."""
    require(heldout >= 0, FIT, f"the number of held-out views must be 0 or more (got {heldout})")
    n_fit = len(corners) - heldout
    require(
        n_fit >= 5,
        FIT,
        f"needs at least 5 views showing the whole board to fit; holding out the last {heldout} of "
        f"{len(corners)} leaves {max(n_fit, 0)}"
        if heldout
        else f"needs at least 5 views showing the whole board to fit (got {len(corners)})",
    )
    obj = board_points(cols, rows, square_m)
    objs = [obj] * len(corners)
    imgs = [np.asarray(c, np.float32).reshape(-1, 1, 2) for c in corners]
    w, h = image_size
    rms, K, D, rvecs, _ = cv2.calibrateCamera(objs[:n_fit], imgs[:n_fit], (w, h), None, None)
    normals = np.array([cv2.Rodrigues(r)[0][:, 2] for r in rvecs])
    tilt = np.degrees(np.arccos(np.clip(np.abs(normals[:, 2]), 0.0, 1.0)))
    spread = float(np.max(tilt))
    require(
        spread > 10.0,
        FIT,
        f"every board is seen nearly face-on (largest tilt {spread:.1f} deg): tilt it by 15-45 deg in some views",
    )
    held = []
    for o, im in zip(objs[n_fit:], imgs[n_fit:], strict=True):
        ok, rv, tv = cv2.solvePnP(o, im, K, D)
        if ok:
            proj, _ = cv2.projectPoints(o, rv, tv, K, D)
            held.append(np.sum((proj.reshape(-1, 2) - im.reshape(-1, 2)) ** 2, 1))
    held_rms = float(np.sqrt(np.mean(np.concatenate(held)))) if held else float("nan")
    d = np.zeros(5)
    d[: min(5, D.size)] = D.ravel()[:5]
    return IntrinsicsResult(
        float(K[0, 0]),
        float(K[1, 1]),
        float(K[0, 2]),
        float(K[1, 2]),
        tuple(float(x) for x in d),  # type: ignore[arg-type]
        w,
        h,
        float(rms),
        held_rms,
        n_fit,
        heldout,
        spread,
    )
