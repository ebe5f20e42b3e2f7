"""The recording's images as one MP4 per image topic, frame k the image nearest (at or before)
the state of dataset row k: what LeRobot stores as `observation.images.*` video features.

Images are streamed in stamp order and each is decoded once (a raw camera topic does not fit
in memory); rows are in time order, so the image each row needs never goes back.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from tiplog.mcap_io import read_messages, read_summary
from tiplog.userio import UserError

# topic -> LeRobot feature key
IMAGE_TOPICS = {"vision/preview": "observation.images.vision_preview", "camera/image": "observation.images.camera"}
CODEC = "mp4v"  # MPEG-4 part 2: written by OpenCV's bundled FFmpeg, read by PyAV and torchcodec


@dataclass
class VideoInfo:
    key: str
    topic: str
    height: int
    width: int
    frames: int = 0
    stats: dict[str, list] = field(default_factory=dict)


def image_topics(recording: Path) -> list[str]:
    summary = read_summary(recording)
    have = {c.topic for c in summary.channels.values()} if summary is not None else set()
    return [t for t in IMAGE_TOPICS if t in have]


def _stamp(msg) -> int:
    return int(msg.timestamp.ToNanoseconds())


def _decode(topic: str, msg) -> np.ndarray:
    """(H, W, 3) uint8 RGB."""
    if topic == "vision/preview":
        img = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise UserError(f"a {topic} image ({msg.format}) does not decode")
        return img[:, :, ::-1]
    if msg.encoding not in ("rgb8", "bgr8"):
        raise UserError(f"{topic}: image encoding {msg.encoding!r} is not exported (rgb8, bgr8)")
    img = (
        np.frombuffer(msg.data, np.uint8)
        .reshape(msg.height, msg.step)[:, : msg.width * 3]
        .reshape(msg.height, msg.width, 3)
    )
    return img if msg.encoding == "rgb8" else img[:, :, ::-1]


def write_video(recording: Path, topic: str, row_stamps_ns: np.ndarray, fps: int, out: Path) -> VideoInfo:
    """One MP4 at `fps` with a frame per row of `row_stamps_ns` (in time order): the image at
    or before each row's state (the first image for rows before it)."""
    stamps = np.array([_stamp(r.message) for r in read_messages(recording, [topic])], np.int64)
    if len(stamps) == 0:
        raise UserError(f"{recording}: no {topic} images")
    order = np.argsort(stamps, kind="stable")
    at = np.clip(np.searchsorted(stamps[order], row_stamps_ns, side="right") - 1, 0, len(order) - 1)
    want = order[at]  # per row: the image's place in the file
    left = Counter(want.tolist())
    cache: dict[int, np.ndarray] = {}  # decoded images some later row still needs
    images = enumerate(read_messages(recording, [topic]))
    writer, info = None, None
    acc = _ChannelStats()
    sample_every = max(len(want) // 200, 1)
    try:
        for k, i in enumerate(want.tolist()):
            while i not in cache:
                pos, rec = next(images)
                if left[pos]:
                    cache[pos] = _decode(topic, rec.message)
            img = cache[i]
            left[i] -= 1
            if not left[i]:
                del cache[i]
            if writer is None:
                h, w = img.shape[:2]
                info = VideoInfo(IMAGE_TOPICS[topic], topic, h, w)
                writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*CODEC), fps, (w, h))
                if not writer.isOpened():
                    raise UserError(f"{out}: OpenCV cannot write {CODEC} video here")
            if img.shape[:2] != (info.height, info.width):
                img = cv2.resize(img, (info.width, info.height))
            writer.write(np.ascontiguousarray(img[:, :, ::-1]))
            if k % sample_every == 0:
                acc.add(img)
    finally:
        if writer is not None:
            writer.release()
    info.frames = len(want)
    info.stats = acc.result()
    return info


class _ChannelStats:
    """Per-channel min, max, mean, std of [0, 1] pixel values, as LeRobot keeps them for
    images (shape (3, 1, 1))."""

    def __init__(self) -> None:
        self.n, self.s, self.sq = 0, np.zeros(3), np.zeros(3)
        self.lo, self.hi = np.ones(3), np.zeros(3)

    def add(self, img: np.ndarray) -> None:
        x = img.reshape(-1, 3) / 255.0
        self.n += 1
        self.s += x.mean(0)
        self.sq += (x**2).mean(0)
        self.lo, self.hi = np.minimum(self.lo, x.min(0)), np.maximum(self.hi, x.max(0))

    def result(self) -> dict[str, list]:
        mean = self.s / self.n
        std = np.sqrt(np.maximum(self.sq / self.n - mean**2, 0.0))

        def col(v: np.ndarray) -> list:
            return [[[float(c)]] for c in v]

        return {"min": col(self.lo), "max": col(self.hi), "mean": col(mean), "std": col(std), "count": [self.n]}
