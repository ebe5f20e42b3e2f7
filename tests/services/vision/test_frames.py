"""Frames in: what the service accepts and how it names what it rejects."""

from __future__ import annotations

import numpy as np
import pytest
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from services.vision.app import NewestFrame
from services.vision.frames import FrameError, decode_frame
from tiplog.geometry.camera import CameraModel
from tiplog.images import raw_image

CAM = CameraModel(8, 4, 10.0, 10.0, 4.0, 2.0)


def _img() -> np.ndarray:
    return np.arange(4 * 8 * 3, dtype=np.uint8).reshape(4, 8, 3)


def test_rgb8_round_trip():
    assert np.array_equal(decode_frame(raw_image(_img(), 5), CAM), _img())


def test_bgr8_is_turned_into_rgb():
    m = raw_image(_img()[:, :, ::-1].copy(), 5, encoding="bgr8")
    assert np.array_equal(decode_frame(m, CAM), _img())


def test_padded_rows_are_read_with_their_step():
    img = _img()
    padded = np.zeros((4, 8 * 3 + 4), np.uint8)
    padded[:, : 8 * 3] = img.reshape(4, -1)
    m = RawImage(width=8, height=4, encoding="rgb8", step=28, data=padded.tobytes())
    assert np.array_equal(decode_frame(m, CAM), img)


@pytest.mark.parametrize(
    "msg, reason",
    [
        (RawImage(width=8, height=4, encoding="mono8", step=8, data=bytes(32)), "bad_encoding"),
        (RawImage(width=16, height=4, encoding="rgb8", step=48, data=bytes(192)), "bad_size"),
        (RawImage(width=8, height=4, encoding="rgb8", step=24, data=bytes(50)), "bad_data"),
        (RawImage(width=8, height=4, encoding="rgb8", step=3, data=bytes(96)), "bad_data"),
    ],
)
def test_bad_frames_are_rejected_with_a_reason(msg, reason):
    with pytest.raises(FrameError) as e:
        decode_frame(msg, CAM)
    assert e.value.reason == reason


def test_newest_frame_replaces_the_stale_one_and_counts_it():
    slot = NewestFrame()
    assert slot.take(0.0) is None
    for i in range(3):
        slot.put(i)
    assert slot.take(0.0) == 2
    assert slot.dropped_stale == 2 and slot.received == 3
    assert slot.take(0.0) is None
