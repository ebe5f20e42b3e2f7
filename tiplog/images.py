"""Camera frames as foxglove.RawImage, the one way every producer builds them."""

from __future__ import annotations

import numpy as np
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
