"""Camera runner thread: connect, read, check, publish camera/image and camera/info; on
any failure report it (log, `camera_*` counters in device/status) and reconnect.

A frame is checked before it is published: HxWx3 uint8, the expected size (the configured
one, else the first frame's), and the encoding asked for. The frame's stamp is the arrival
stamp the source took before any processing.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable

from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from tiplog.bus import Bus
from tiplog.clock import NS_PER_S, now_ns
from tiplog.images import raw_image

from .cameras import Camera, CameraConfig, CameraReadError, EndOfStreamError, Frame, Intrinsics, make_camera
from .cameras.calibration import to_message
from .status import GatewayStatus

log = logging.getLogger("tiplog.sensor_gateway.camera")


class BadFrameError(ValueError):
    """A frame of the wrong shape, size, type or encoding."""


class CameraRunner:
    """Publishes one camera on its own thread until `stop()`."""

    def __init__(
        self,
        config: CameraConfig,
        bus: Bus,
        status: GatewayStatus,
        calibration: Intrinsics | None = None,
        *,
        stall_timeout_s: float = 2.0,
        reconnect_s: float = 0.5,
        info_period_s: float = 1.0,
        camera_factory: Callable[[CameraConfig], Camera] = make_camera,
    ) -> None:
        self.config = config
        self.status = status
        self.calibration = calibration
        self.stall_timeout_s = stall_timeout_s
        self.reconnect_s = reconnect_s
        self.info_period_s = info_period_s
        self._factory = camera_factory
        self.faults: Counter[str] = Counter()
        self.published = 0
        self._image_pub = bus.publisher("camera/image")
        self._info_pub = bus.publisher("camera/info")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camera", daemon=True)
        self._size: tuple[int, int] | None = (config.height, config.width) if config.width and config.height else None

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 3.0) -> None:
        self._stop.set()
        self._thread.join(timeout_s)

    def _fault(self, kind: str, message: str) -> None:
        self.faults[kind] += 1
        self.status.set_faults(self.faults, prefix="camera_")
        n = self.faults[kind]
        if n <= 5 or n % 100 == 0:
            log.warning("camera %s (%d so far): %s", kind, n, message)

    def _run(self) -> None:
        connected_once = False
        while not self._stop.is_set():
            cam = self._factory(self.config)
            try:
                cam.connect()
            except (CameraReadError, OSError, RuntimeError, ValueError) as e:
                self._fault("connect_failures", str(e))
                self._stop.wait(self.reconnect_s)
                continue
            if connected_once:
                self._fault("reconnects", f"{cam} reconnected")
            connected_once = True
            log.info("camera %s connected", cam)
            try:
                self._stream(cam)
            finally:
                try:
                    cam.disconnect()
                except Exception as e:  # a broken SDK must not stop the runner
                    log.warning("camera disconnect failed: %s", e)
            self._stop.wait(self.reconnect_s)

    def _stream(self, cam: Camera) -> None:
        intrinsics = cam.intrinsics() or self.calibration
        next_info = 0
        waited_s = 0.0
        slice_s = min(0.2, self.stall_timeout_s)  # short waits: stop() is honoured quickly
        while not self._stop.is_set():
            try:
                frame = cam.async_read(slice_s * 1000.0)
                waited_s = 0.0
            except EndOfStreamError as e:
                log.info("camera: %s; no more frames from this source", e)
                self.status.set_faults({"end_of_stream": 1}, prefix="camera_")
                self._stop.set()
                return
            except TimeoutError:
                waited_s += slice_s
                if waited_s < self.stall_timeout_s:
                    continue
                self._fault("stalls", f"no frame for {self.stall_timeout_s:.1f} s")
                return
            except CameraReadError as e:
                self._fault("read_errors", str(e))
                return
            try:
                self._check(frame)
            except BadFrameError as e:
                self._fault("bad_frames", str(e))
                return
            self._image_pub.put(self.to_raw_image(frame))
            self.published += 1
            self.status.on_camera_frame()
            now = now_ns()
            if intrinsics is not None and now >= next_info:
                self._info_pub.put(to_message(intrinsics, frame.stamp_ns))
                next_info = now + int(self.info_period_s * NS_PER_S)

    def _check(self, frame: Frame) -> None:
        img = frame.image
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype.name != "uint8":
            raise BadFrameError(f"frame is {img.dtype.name} {img.shape}, expected HxWx3 uint8")
        want_enc = f"{self.config.color}8"
        if frame.encoding != want_enc:
            raise BadFrameError(f"frame encoding {frame.encoding!r}, expected {want_enc!r}")
        if self._size is None:
            self._size = img.shape[:2]
        elif img.shape[:2] != self._size:
            h, w = self._size
            raise BadFrameError(f"frame is {img.shape[1]}x{img.shape[0]}, expected {w}x{h}")

    @staticmethod
    def to_raw_image(frame: Frame) -> RawImage:
        """foxglove.RawImage stamped with the frame's arrival, frame_id "camera"."""
        return raw_image(frame.image, frame.stamp_ns, "camera", frame.encoding)
