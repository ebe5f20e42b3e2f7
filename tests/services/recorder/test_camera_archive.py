"""Camera frames archived as JPEG by default (camera/image/compressed, foxglove.CompressedImage)
and raw on request; what vision reads back from the archive is the frame, stamp and all."""

from __future__ import annotations

import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from services.recorder.camera_archive import CameraArchive
from services.vision.frames import decode_frame, recording_frames
from tiplog.images import decompress, raw_image
from tiplog.mcap_io import read_messages
from tiplog.v1 import recorder_pb2

A = recorder_pb2.RecorderAction
S = recorder_pb2.RecorderState


def _frame(seed: int = 0, w: int = 320, h: int = 180) -> np.ndarray:
    """A smooth scene with edges (as a camera sees a shaft) plus a little noise."""
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.stack([(xx * 255 // w), (yy * 255 // h), np.full_like(xx, 60)], axis=2).astype(np.uint8)
    img[h // 3 : h // 2, :, :] = (230, 40, 20)  # a red band: a channel swap would show
    rng = np.random.default_rng(seed)
    return np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)


def _psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(float) - b.astype(float)) ** 2)
    return float("inf") if mse == 0 else float(10 * np.log10(255.0**2 / mse))


def test_jpeg_round_trip_keeps_the_frame_its_stamp_and_channel_order():
    img = _frame()
    raw = raw_image(img, 123_456_789_012, frame_id="cam0")
    arch = CameraArchive(["camera/image"], quality=90)
    assert arch.wants("camera/image", "foxglove.RawImage") and not arch.wants("camera/info", "foxglove.RawImage")
    topic, type_name, payload = arch.encode("camera/image", raw.SerializeToString())
    assert (topic, type_name) == ("camera/image/compressed", "foxglove.CompressedImage")
    assert len(payload) < len(raw.data) / 4
    back = decompress(CompressedImage.FromString(payload))
    assert back.timestamp.ToNanoseconds() == 123_456_789_012 and back.frame_id == "cam0"
    decoded = decode_frame(back, None)
    assert _psnr_db(decoded, img) > 35 and _psnr_db(decoded[:, :, ::-1], img) < 20  # red stays red
    bgr = raw_image(img[:, :, ::-1].copy(), 1, encoding="bgr8")
    same = decompress(CompressedImage.FromString(arch.encode("camera/image", bgr.SerializeToString())[2]))
    assert _psnr_db(decode_frame(same, None), img) > 35


def test_a_frame_that_cannot_be_read_is_refused_not_guessed():
    arch = CameraArchive(["camera/image"])
    bad = RawImage(width=10, height=10, encoding="rgb8", step=30, data=b"\x00" * 20)
    with pytest.raises(ValueError, match="bytes for a 10x10"):
        arch.encode("camera/image", bad.SerializeToString())
    with pytest.raises(ValueError, match="quality"):
        CameraArchive(["camera/image"], quality=0)


@pytest.mark.parametrize("archive", ["jpeg", "raw"])
def test_the_recorder_archives_camera_frames_as_configured(served_recorder, tmp_path, archive):
    srv = served_recorder(camera_archive=archive)
    srv_start = recorder_pb2.RecorderCommand(action=A.RECORDER_ACTION_START, session=f"cam_{archive}")
    from tiplog import topics

    replies = srv.bus.request(topics.RECORDER_COMMAND, srv_start.SerializeToString(), timeout_s=10)
    assert recorder_pb2.RecorderReply.FromString(replies[0]).ok
    pub = srv.bus.publisher("camera/image")
    frames = [_frame(k) for k in range(5)]
    for k, img in enumerate(frames):
        pub.put(raw_image(img, 1_000 + k))
    srv.status.wait(lambda s: s.topics["camera/image"].written == 5)
    stop = recorder_pb2.RecorderCommand(action=A.RECORDER_ACTION_STOP)
    srv.bus.request(topics.RECORDER_COMMAND, stop.SerializeToString(), timeout_s=10)
    srv.status.wait(lambda s: s.state == S.RECORDER_STATE_IDLE)
    path = tmp_path / "rec" / f"cam_{archive}_000.mcap"
    by_topic: dict[str, int] = {}
    for r in read_messages(path):
        by_topic[r.topic] = by_topic.get(r.topic, 0) + 1
    expect = "camera/image/compressed" if archive == "jpeg" else "camera/image"
    assert by_topic.get(expect) == 5 and sum(v for t, v in by_topic.items() if t.startswith("camera/")) == 5
    got = list(recording_frames(path))  # what `tiplog vision run` and training read
    assert [g[2].timestamp.ToNanoseconds() for g in got] == [1_000 + k for k in range(5)]
    for (_, _, msg, _), img in zip(got, frames, strict=True):
        psnr = _psnr_db(decode_frame(msg, None), img)
        assert psnr > 35 if archive == "jpeg" else psnr == float("inf")  # raw: bit for bit
