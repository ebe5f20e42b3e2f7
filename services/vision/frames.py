"""Camera frames in, checked: a foxglove.RawImage becomes an (H, W, 3) uint8 RGB array of the
calibrated camera's size, or a FrameError whose reason names what is wrong (the service counts
and reports it and carries on)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from tiplog.geometry.camera import CameraModel
from tiplog.images import decompress
from tiplog.mcap_io import read_messages

ENCODINGS = {"rgb8": (3, False), "bgr8": (3, True)}
COMPRESSED_TOPIC = "camera/image/compressed"  # the recorder's archive of camera/image


class FrameError(ValueError):
    """A frame that cannot be processed; `reason` is a short token for the observation."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def decode_frame(msg: RawImage, camera: CameraModel | None) -> np.ndarray:
    """RawImage -> (H, W, 3) uint8 RGB (a view on the payload when possible)."""
    if msg.encoding not in ENCODINGS:
        raise FrameError("bad_encoding", f"encoding {msg.encoding!r}; expected one of {', '.join(ENCODINGS)}")
    if camera is not None and (msg.width, msg.height) != (camera.width, camera.height):
        raise FrameError("bad_size", f"frame is {msg.width}x{msg.height}, the camera is {camera.width}x{camera.height}")
    if msg.width <= 0 or msg.height <= 0:
        raise FrameError("bad_size", f"frame is {msg.width}x{msg.height}")
    row = msg.width * 3
    step = msg.step or row
    data = msg.data  # each read of a bytes field copies it out of the message: read it once
    if step < row or len(data) < step * (msg.height - 1) + row:
        raise FrameError("bad_data", f"{len(data)} bytes for {msg.width}x{msg.height} {msg.encoding} (step {msg.step})")
    buf = np.frombuffer(data, np.uint8)
    if step == row and len(buf) >= row * msg.height:
        img = buf[: row * msg.height].reshape(msg.height, msg.width, 3)
    else:
        img = np.lib.stride_tricks.as_strided(buf, (msg.height, msg.width, 3), (step, 3, 1))
    if ENCODINGS[msg.encoding][1]:
        img = img[:, :, ::-1]
    return np.ascontiguousarray(img)


def recording_frames(path: str | Path, every: int = 1) -> Iterator[tuple[int, int, RawImage, CameraModel | None]]:
    """(index, log_time_ns, RawImage, latest camera model or None) for every `every`-th
    camera frame of a recording, in log-time order: camera/image as it was sent, or
    camera/image/compressed (the recorder's JPEG archive) decoded."""
    camera: CameraModel | None = None
    k = 0
    for rec in read_messages(path, ["camera/image", COMPRESSED_TOPIC, "camera/info"]):
        if rec.topic == "camera/info":
            camera = CameraModel.from_calibration(rec.message)
            continue
        if k % every == 0:
            frame = decompress(rec.message) if rec.topic == COMPRESSED_TOPIC else rec.message
            yield k, rec.log_time_ns, frame, camera
        k += 1
