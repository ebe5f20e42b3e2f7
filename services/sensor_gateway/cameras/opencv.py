"""Any OpenCV VideoCapture source: a device index, a video file, a stream URL."""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from .base import Camera, CameraConfig, CameraReadError, ColorOrder, EndOfStreamError


@dataclass
class OpenCVCameraConfig(CameraConfig):
    source: int | str = 0  # device index, file path or URL
    loop: bool = False  # restart a file at its end instead of reporting the end
    pace: bool = False  # for files: deliver at `fps` (or the file's rate) instead of at once

    def __post_init__(self) -> None:
        super().__post_init__()
        if isinstance(self.source, str) and self.source.strip().isdigit():
            self.source = int(self.source)


class OpenCVCamera(Camera):
    config: OpenCVCameraConfig

    def __init__(self, config: OpenCVCameraConfig) -> None:
        super().__init__(config)
        self._cap: cv2.VideoCapture | None = None
        self._is_file = isinstance(config.source, str)
        self._period_s = 0.0
        self._next_t = 0.0

    def __str__(self) -> str:
        return f"OpenCVCamera({self.config.source!r})"

    def _native_order(self) -> ColorOrder:
        return "bgr"

    def _connect(self) -> None:
        cap = cv2.VideoCapture(self.config.source)
        if not cap.isOpened():
            cap.release()
            raise CameraReadError(f"OpenCV cannot open {self.config.source!r}")
        if not self._is_file:
            if self.config.width:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.config.width)
            if self.config.height:
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.config.height)
            if self.config.fps:
                cap.set(cv2.CAP_PROP_FPS, self.config.fps)
        fps = self.config.fps or cap.get(cv2.CAP_PROP_FPS) or 0.0
        self._period_s = 1.0 / fps if (self._is_file and self.config.pace and fps > 0) else 0.0
        self._next_t = time.monotonic()
        self._cap = cap

    def _grab(self) -> tuple[np.ndarray, int]:
        if self._cap is None:
            raise CameraReadError(f"{self} is not open")
        if self._period_s:
            delay = self._next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self._next_t = max(self._next_t + self._period_s, time.monotonic() - self._period_s)
        ok, image = self._cap.read()
        stamp = self._now()
        if not ok and self._is_file and self.config.loop:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, image = self._cap.read()
            stamp = self._now()
        if not ok or image is None:
            if self._is_file and self._cap.get(cv2.CAP_PROP_FRAME_COUNT) > 0:
                raise EndOfStreamError(f"{self}: end of file")
            raise CameraReadError(f"{self}: no frame (device lost?)")
        return image, stamp

    def _disconnect(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
