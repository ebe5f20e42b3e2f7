"""Camera frames as foxglove.RawImage, the one way every producer builds them."""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage


def raw_image(img: np.ndarray, stamp_ns: int, frame_id: str = "camera", encoding: str = "rgb8") -> RawImage:
    """(H, W, 3) uint8 frame -> foxglove.RawImage stamped `stamp_ns` (capture, host clock)."""
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 frame, got {img.shape} {img.dtype}")
    m = RawImage(
        frame_id=frame_id,
        width=int(img.shape[1]),
        height=int(img.shape[0]),
        encoding=encoding,
        step=int(img.shape[1] * 3),
        data=np.ascontiguousarray(img).tobytes(),
    )
    m.timestamp.FromNanoseconds(int(stamp_ns))
    return m


def decompress(msg: CompressedImage) -> RawImage:
    """A foxglove.CompressedImage (JPEG or PNG: an archived camera frame) as the rgb8 RawImage
    it was made from, with the same stamp and frame; ValueError when it does not decode."""
    import cv2

    img = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"not a decodable {msg.format or 'image'} ({len(msg.data)} bytes)")
    out = raw_image(cv2.cvtColor(img, cv2.COLOR_BGR2RGB), 0, frame_id=msg.frame_id)
    out.timestamp.CopyFrom(msg.timestamp)
    return out
