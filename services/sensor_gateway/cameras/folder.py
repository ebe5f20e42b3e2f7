"""A folder of images (PNG, JPEG, ...), in name order, as a camera."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .base import Camera, CameraConfig, CameraReadError, ColorOrder, EndOfStreamError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass
class FolderCameraConfig(CameraConfig):
    path: str = ""
    loop: bool = False  # start again after the last image
    # fps > 0 paces delivery at that rate; 0 delivers as fast as read() is called.


class FolderCamera(Camera):
    config: FolderCameraConfig

    def __init__(self, config: FolderCameraConfig) -> None:
        super().__init__(config)
        self._files: list[Path] = []
        self._index = 0
        self._next_t = 0.0

    def __str__(self) -> str:
        return f"FolderCamera({self.config.path!r})"

    def _native_order(self) -> ColorOrder:
        return "bgr"

    def _connect(self) -> None:
        folder = Path(self.config.path)
        if not folder.is_dir():
            raise CameraReadError(f"image folder {folder} does not exist")
        self._files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self._files:
            raise CameraReadError(f"image folder {folder} holds no {'/'.join(IMAGE_SUFFIXES)} files")
        self._index = 0
        self._next_t = time.monotonic()

    def _grab(self) -> tuple[np.ndarray, int]:
        if self._index >= len(self._files):
            if not self.config.loop:
                raise EndOfStreamError(f"{self}: after the last of {len(self._files)} images")
            self._index = 0
        if self.config.fps:
            delay = self._next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self._next_t = max(self._next_t + 1.0 / self.config.fps, time.monotonic() - 1.0 / self.config.fps)
        path = self._files[self._index]
        self._index += 1
        data = np.fromfile(path, dtype=np.uint8)
        stamp = self._now()  # the file's bytes have arrived; decoding is processing
        image = cv2.imdecode(data, cv2.IMREAD_COLOR)
        if image is None:
            raise CameraReadError(f"{path} is not a readable image")
        return image, stamp

    def _disconnect(self) -> None:
        self._files = []
