"""vision/preview: a small JPEG of the frame with the network's mask tinted, the labeler's two
silhouette lines and the junction drawn (lines are straight in undistorted pixels, so they are
drawn as polylines through the lens distortion). Green when the frame was accepted, orange
when the gate rejected it."""

from __future__ import annotations

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

from services.vision.pipeline import FrameResult
from tiplog.geometry.camera import CameraModel


def _line_polyline(line: np.ndarray, cam: CameraModel, scale: float, n: int = 24) -> np.ndarray | None:
    """Points (k, 1, 2) int32 of an undistorted-pixel line, distorted and scaled to the preview."""
    a, b, c = line
    if abs(b) > abs(a):  # mostly horizontal: walk u
        u = np.linspace(0, cam.width - 1, n)
        v = -(a * u + c) / b
    else:
        v = np.linspace(0, cam.height - 1, n)
        u = -(b * v + c) / a
    xy = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy], -1)
    d = cam.distort_normalized(xy)
    pts = np.stack([cam.fx * d[:, 0] + cam.cx, cam.fy * d[:, 1] + cam.cy], -1) * scale
    ok = np.all(np.isfinite(pts), 1) & (np.abs(pts) < 1e5).all(1)
    return pts[ok].round().astype(np.int32)[:, None, :] if ok.sum() >= 2 else None


def render_preview(frame_rgb: np.ndarray, res: FrameResult, cam: CameraModel, width_px: int = 320) -> np.ndarray:
    """The preview picture (h, width_px, 3) uint8 RGB."""
    scale = width_px / frame_rgb.shape[1]
    h = int(round(frame_rgb.shape[0] * scale))
    img = cv2.resize(frame_rgb, (width_px, h), interpolation=cv2.INTER_AREA)
    if res.prob is not None:
        m = cv2.resize((res.prob > 0.5).astype(np.uint8), (width_px, h), interpolation=cv2.INTER_NEAREST) > 0
        img[m] = (0.5 * img[m] + np.array([0, 0, 110])).astype(np.uint8)
    colour = (40, 220, 40) if res.obs.accepted else (255, 140, 0)
    lab = res.label
    if lab.ok:
        for line in (lab.line_left, lab.line_right):
            pts = _line_polyline(line, cam, scale)
            if pts is not None:
                cv2.polylines(img, [pts], False, colour, 1, cv2.LINE_AA)
    if res.obs.junction_visible:
        j = cam.project(np.array([res.obs.junction_ray.x, res.obs.junction_ray.y, res.obs.junction_ray.z]))
        if np.all(np.isfinite(j)):
            cv2.circle(img, tuple(int(round(c * scale)) for c in j), 4, (255, 255, 0), 1, cv2.LINE_AA)
    return img


def preview_message(
    frame_rgb: np.ndarray, res: FrameResult, cam: CameraModel, width_px: int = 320, quality: int = 70
) -> CompressedImage:
    """foxglove.CompressedImage (jpeg) stamped with the frame's capture stamp."""
    img = render_preview(frame_rgb, res, cam, width_px)
    ok, buf = cv2.imencode(".jpg", img[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding of the preview failed")
    m = CompressedImage(frame_id=cam.frame_id, format="jpeg", data=buf.tobytes())
    m.timestamp.FromNanoseconds(int(res.obs.header.stamp_ns))
    return m
