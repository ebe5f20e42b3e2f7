"""Training data for the network, as the paper made it: frames of recordings labelled by the
labeler, split by pose (a quarter of the poses held out), and synthetic composites (one frame's
instrument pasted, moved and turned, onto another frame's background) for half of each batch.

Everything is stored at the network's input resolution (NetSpec: 256x144 for 1280x720).
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from services.vision import edges
from services.vision.frames import FrameError, decode_frame, recording_frames
from services.vision.labeler import LabelerParams, ShaftLabel, label_frame, label_mask
from services.vision.network import NetSpec, downsample

log = logging.getLogger(__name__)


@dataclass
class LabeledFrames:
    """(n, h, w, 3) uint8 images, (n, h, w) uint8 shaft masks and instrument regions (shaft and
    jaws, for composites), and one pose key per frame."""

    images: np.ndarray
    masks: np.ndarray
    regions: np.ndarray
    pose_keys: list[tuple[int, int, int]]

    def __len__(self) -> int:
        return len(self.images)


def pose_key(lab: ShaftLabel, cell_px: float = 96.0, angle_deg: float = 12.0) -> tuple[int, int, int]:
    """A coarse pose bin from the label: where the shaft's distal end is and where it points."""
    j = lab.junction_px if lab.junction_visible else -lab.line_left[2] * lab.line_left[:2]
    ang = np.degrees(np.arctan2(lab.direction[1], lab.direction[0]))
    return int(j[0] // cell_px), int(j[1] // cell_px), int((ang + 180.0) // angle_deg)


def instrument_region(lab: ShaftLabel, mask: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The shaft mask plus a disc over the jaws beyond the junction, dilated by one pixel (uint8)."""
    reg = mask.astype(np.uint8)
    if lab.junction_visible:
        width = float(lab.line_left[:2] @ lab.junction_px + lab.line_left[2])
        width += float(lab.line_right[:2] @ lab.junction_px + lab.line_right[2])
        c = lab.junction_px + 0.45 * width * lab.direction
        reg |= (np.linalg.norm(uv - c, axis=-1) < 0.75 * width).astype(np.uint8)
    return cv2.dilate(reg, np.ones((3, 3), np.uint8))


def label_recordings(
    paths: Sequence[str | Path],
    spec: NetSpec,
    params: LabelerParams | None = None,
    every: int = 1,
    progress: Callable[[str], None] | None = None,
) -> LabeledFrames:
    """Label every `every`-th frame of the recordings; frames the labeler cannot label are skipped."""
    imgs, masks, regs, keys = [], [], [], []
    skipped = 0
    for path in paths:
        for k, _, msg, cam in recording_frames(path, every):
            if cam is None:
                raise ValueError(f"{path}: camera/image before any camera/info; cannot undistort")
            try:
                frame = decode_frame(msg, cam)
            except FrameError:
                skipped += 1
                continue
            lab = label_frame(frame, cam, params)
            if not lab.ok:
                skipped += 1
                continue
            uv = edges.grid_undistorted(cam, float(spec.step), spec.grid_offset, spec.in_h, spec.in_w)
            m = label_mask(lab, uv)
            imgs.append(downsample(frame, spec))
            masks.append(m.astype(np.uint8))
            regs.append(instrument_region(lab, m, uv))
            keys.append(pose_key(lab))
            if progress and len(imgs) % 50 == 0:
                progress(f"labelled {len(imgs)} frames ({skipped} skipped) from {Path(path).name} frame {k}")
    if not imgs:
        raise ValueError("the labeler found no shaft in any frame of the recordings")
    if progress:
        progress(f"labelled {len(imgs)} frames ({skipped} skipped)")
    return LabeledFrames(np.stack(imgs), np.stack(masks), np.stack(regs), keys)


def split_by_pose(frames: LabeledFrames, held_out: float = 0.25, salt: str = "0") -> tuple[np.ndarray, np.ndarray]:
    """(train, held-out) frame indices: whole pose bins go to one side, chosen by a hash of the
    bin (deterministic), so that no pose is both trained on and tested."""
    u = np.array([int(hashlib.sha256(f"{salt}:{k}".encode()).hexdigest()[:8], 16) / 2**32 for k in frames.pose_keys])
    test = u < held_out
    if test.all() or not test.any():  # too few poses to split by bin: fall back to every 4th bin
        test = np.arange(len(u)) % 4 == 0
    return np.nonzero(~test)[0], np.nonzero(test)[0]


def backgrounds(frames: LabeledFrames) -> np.ndarray:
    """Each frame with its instrument region inpainted (n, h, w, 3) uint8."""
    return np.stack(
        [cv2.inpaint(img, cv2.dilate(reg, np.ones((3, 3), np.uint8)), 3, cv2.INPAINT_TELEA)
         for img, reg in zip(frames.images, frames.regions, strict=True)]
    )  # fmt: skip


def composite(
    frames: LabeledFrames, bgs: np.ndarray, i_fg: int, i_bg: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(image, mask): frame i_fg's instrument turned (+-25 deg) and moved (+-20 % of the frame)
    about its middle, pasted with a soft edge onto frame i_bg's background, brightness jittered."""
    h, w = frames.masks.shape[1:]
    ang = rng.uniform(-25.0, 25.0)
    ys, xs = np.nonzero(frames.regions[i_fg])
    c = (float(xs.mean()), float(ys.mean())) if len(xs) else (w / 2, h / 2)
    M = cv2.getRotationMatrix2D(c, ang, 1.0)
    M[:, 2] += rng.uniform(-0.2, 0.2, 2) * (w, h)
    flip = rng.random() < 0.5
    fg, reg, msk = frames.images[i_fg], frames.regions[i_fg], frames.masks[i_fg]
    if flip:
        fg, reg, msk = fg[:, ::-1], reg[:, ::-1], msk[:, ::-1]
    fg_w = cv2.warpAffine(np.ascontiguousarray(fg), M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    a = cv2.warpAffine(np.ascontiguousarray(reg).astype(np.float32), M, (w, h), flags=cv2.INTER_LINEAR)
    a = cv2.GaussianBlur(a, (0, 0), 0.6)[..., None]
    m = cv2.warpAffine(np.ascontiguousarray(msk), M, (w, h), flags=cv2.INTER_NEAREST)
    img = a * fg_w.astype(np.float32) + (1.0 - a) * bgs[i_bg].astype(np.float32)
    img *= rng.uniform(0.8, 1.2)
    return np.clip(img, 0, 255).astype(np.uint8), m
