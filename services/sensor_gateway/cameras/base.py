"""The camera interface every source implements (after lerobot's `Camera`).

    with OpenCVCamera(OpenCVCameraConfig(source="clip.avi")) as cam:
        frame = cam.read()            # blocking, the next frame
        frame = cam.async_read(200)   # the newest frame from a background reader thread

A `Frame` carries its arrival stamp (host clock, ns), taken the moment the backend handed
the frame over and before any conversion.
"""

from __future__ import annotations

import abc
import threading
from dataclasses import dataclass
from typing import Literal

import numpy as np

from tiplog.clock import now_ns

ColorOrder = Literal["rgb", "bgr"]


class DeviceNotConnectedError(RuntimeError):
    """The camera is not connected (call connect() first, or it was lost)."""


class DeviceAlreadyConnectedError(RuntimeError):
    """connect() on a camera that is already connected."""


class CameraReadError(RuntimeError):
    """The source delivered no frame (timeout, device gone, unreadable data)."""


class EndOfStreamError(CameraReadError):
    """A finite source (file, folder) has no more frames."""


@dataclass
class CameraConfig:
    """Fields every backend has. width/height 0: whatever the source delivers."""

    width: int = 0
    height: int = 0
    fps: float = 0.0  # 0: as the source delivers
    color: ColorOrder = "rgb"

    def __post_init__(self) -> None:
        if self.width < 0 or self.height < 0:
            raise ValueError(f"width/height must be >= 0, got {self.width}x{self.height}")
        if self.fps < 0:
            raise ValueError(f"fps must be >= 0, got {self.fps}")
        if self.color not in ("rgb", "bgr"):
            raise ValueError(f"color must be 'rgb' or 'bgr', got {self.color!r}")


@dataclass(frozen=True, slots=True)
class Frame:
    """One image, HxWx3 uint8, channels in `encoding` order ("rgb8" or "bgr8")."""

    image: np.ndarray
    stamp_ns: int  # arrival on the host clock, before any processing
    encoding: str
    seq: int


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics as the device reports them (pixels)."""

    width: int
    height: int
    K: tuple[float, ...]  # 3x3 row-major
    D: tuple[float, ...]
    distortion_model: str  # "plumb_bob" (k1 k2 p1 p2 k3) or "rational_polynomial"


class Camera(abc.ABC):
    """Base class: subclasses implement `_connect`, `_grab` and `_disconnect`."""

    def __init__(self, config: CameraConfig) -> None:
        self.config = config
        self._connected = False
        self._seq = 0
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._latest: Frame | None = None
        self._latest_error: Exception | None = None
        self._new = threading.Condition()

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        if self._connected:
            raise DeviceAlreadyConnectedError(f"{self} is already connected")
        self._connect()
        self._connected = True

    def intrinsics(self) -> Intrinsics | None:
        """Intrinsics reported by the device itself, if it reports any."""
        return None

    def read(self) -> Frame:
        """The next frame, blocking; CameraReadError if the source gave none."""
        if not self._connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        image, stamp = self._grab()
        return self._frame(image, stamp)

    def _frame(self, image: np.ndarray, stamp_ns: int) -> Frame:
        # The backend delivers BGR (OpenCV) or RGB (RealSense); convert only on request.
        native = self._native_order()
        if self.config.color != native:
            image = np.ascontiguousarray(image[..., ::-1])
        self._seq += 1
        return Frame(image, stamp_ns, f"{self.config.color}8", self._seq - 1)

    def async_read(self, timeout_ms: float = 200.0) -> Frame:
        """The newest frame not returned before, read by a background thread."""
        if not self._connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._reader, name=f"{type(self).__name__}-reader", daemon=True)
            self._thread.start()
        with self._new:
            if self._latest is None and self._latest_error is None:
                self._new.wait(timeout_ms / 1000.0)
            frame, err = self._latest, self._latest_error
            if frame is not None:
                self._latest = None
                return frame
            self._latest_error = None
        if err is not None:
            raise err
        raise TimeoutError(f"{self}: no frame within {timeout_ms:.0f} ms")

    def _reader(self) -> None:
        while not self._stop.is_set():
            try:
                frame, err = self.read(), None
            except (CameraReadError, DeviceNotConnectedError) as e:
                frame, err = None, e
            with self._new:
                # A newer frame replaces an unread one (latest wins); an error waits
                # behind an unread frame so that the frame is not lost to it.
                if frame is not None:
                    self._latest, self._latest_error = frame, None
                else:
                    self._latest_error = err
                self._new.notify_all()
            if err is not None:
                self._stop.wait(0.05)

    def disconnect(self) -> None:
        if not self._connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)  # a read blocked in a driver is left to finish alone
            self._thread = None
        self._connected = False
        self._disconnect()

    def __enter__(self) -> Camera:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._connected:
            self.disconnect()

    @staticmethod
    def _now() -> int:
        return now_ns()

    @abc.abstractmethod
    def _native_order(self) -> ColorOrder: ...

    @abc.abstractmethod
    def _connect(self) -> None: ...

    @abc.abstractmethod
    def _grab(self) -> tuple[np.ndarray, int]:
        """(HxWx3 uint8 image in native order, arrival stamp ns)."""

    @abc.abstractmethod
    def _disconnect(self) -> None: ...
