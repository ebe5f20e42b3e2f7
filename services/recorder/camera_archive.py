"""Camera frames archived compressed: a foxglove.RawImage becomes a foxglove.CompressedImage
(JPEG, OpenCV) on `<topic>/compressed`, so that a case of hours fits on the cart's disk.

JPEG rather than H.264: each frame is encoded and decodable alone, so a recorder killed
mid-case loses no more than the frames in its unflushed chunk (an H.264 stream loses the
rest of its group of pictures), and its cost per frame is steady on a two-core cart.
"""

from __future__ import annotations

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

RAW_TYPE = RawImage.DESCRIPTOR.full_name
COMPRESSED_TYPE = CompressedImage.DESCRIPTOR.full_name
SUFFIX = "/compressed"
# Channel order of each raw encoding in OpenCV's terms (it encodes BGR).
_TO_BGR = {"rgb8": cv2.COLOR_RGB2BGR, "bgr8": None, "mono8": None}


class CameraArchive:
    """Encodes RawImage payloads of `topics` as JPEG CompressedImage payloads."""

    def __init__(self, topics: list[str], quality: int = 90):
        if not 1 <= quality <= 100:
            raise ValueError(f"JPEG quality must be 1..100 (got {quality})")
        self.topics = frozenset(topics)
        self.quality = quality

    def wants(self, topic: str, type_name: str) -> bool:
        return topic in self.topics and type_name == RAW_TYPE

    def encode(self, topic: str, payload: bytes) -> tuple[str, str, bytes]:
        """(topic, type name, payload) of the compressed frame; ValueError for a frame that
        cannot be read (kept raw by the caller)."""
        msg = RawImage.FromString(payload)
        img = _pixels(msg)
        ok, jpeg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            raise ValueError(f"JPEG encoding of a {msg.width}x{msg.height} {msg.encoding} frame failed")
        out = CompressedImage(frame_id=msg.frame_id, data=jpeg.tobytes(), format="jpeg")
        out.timestamp.CopyFrom(msg.timestamp)
        return topic + SUFFIX, COMPRESSED_TYPE, out.SerializeToString()


def _pixels(msg: RawImage) -> np.ndarray:
    """The frame as OpenCV wants it to encode: (H, W, 3) BGR or (H, W) grey, uint8."""
    if msg.encoding not in _TO_BGR:
        raise ValueError(f"encoding {msg.encoding!r} is not archived compressed")
    channels = 1 if msg.encoding == "mono8" else 3
    row = msg.width * channels
    step = msg.step or row
    data = msg.data
    if msg.width <= 0 or msg.height <= 0 or step < row or len(data) < step * (msg.height - 1) + row:
        raise ValueError(f"{len(data)} bytes for a {msg.width}x{msg.height} {msg.encoding} frame")
    buf = np.frombuffer(data, np.uint8)
    rows = np.lib.stride_tricks.as_strided(buf, (msg.height, row), (step, 1))
    img = rows.reshape(msg.height, msg.width, channels) if channels == 3 else rows
    conv = _TO_BGR[msg.encoding]
    return cv2.cvtColor(img, conv) if conv is not None else np.ascontiguousarray(img)
