"""`tiplog vision run IN.mcap --out OUT.mcap`: every frame of a recording through the same
pipeline as the live service. The output holds vision/observation (logged at each frame's
capture stamp, which its header carries unchanged) beside every other topic and metadata record
of the input except the camera frames (camera/image, or camera/image/compressed: the
recorder's JPEG archive, decoded), so that it is a complete session for offline fusion. On the
CPU the observations are deterministic (all but the processing time), whatever the number of
workers."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from pathlib import Path

from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf import any_pb2  # noqa: F401  (the recorder's _rejected/ channels are copied too)

from services.vision.frames import COMPRESSED_TOPIC, FrameError, decode_frame
from services.vision.network import load_checkpoint
from services.vision.overlap import ordered_map
from services.vision.pipeline import Pipeline
from tiplog.calibration import Calibration, CalibrationError
from tiplog.geometry.camera import CameraModel
from tiplog.images import decompress
from tiplog.mcap_io import McapWriter, raw_messages, read_metadata, read_summary
from tiplog.progress import Progress
from tiplog.userio import UserError
from tiplog.v1 import vision_pb2

OBS_TYPE = vision_pb2.VisionObservation.DESCRIPTOR.full_name
FRAME_TOPICS = ("camera/image", COMPRESSED_TOPIC)


def _calibration(src: Path, calib_path: Path | None) -> Calibration:
    try:
        if calib_path is not None:
            return Calibration.load_yaml(calib_path)
        return Calibration.from_mcap_metadata(read_metadata(src), where=str(src))
    except CalibrationError as e:
        raise UserError(str(e)) from None


def _frame_count(src: Path) -> int:
    summary = read_summary(src)
    if summary is None or summary.statistics is None:
        return 0
    ids = [c.id for c in summary.channels.values() if c.topic in FRAME_TOPICS]
    return sum(summary.statistics.channel_message_counts.get(i, 0) for i in ids)


def run_file(
    src: Path,
    out: Path,
    weights: Path,
    calib_path: Path | None = None,
    device: str = "cpu",
    threads: int = 1,
    quiet: bool = False,
    workers: int = 2,
) -> dict:
    """Process every camera/image of `src` into `out`; returns counts, seconds and frames/s.

    `workers` frames are processed side by side (services.vision.overlap), each with `threads`
    torch threads, while this thread reads, decodes and writes; the output is the same, in the
    same order, for any number of workers."""
    import torch

    if threads > 0:
        torch.set_num_threads(threads)
    calib = _calibration(src, calib_path)
    try:
        seg, _ = load_checkpoint(weights, device)
    except ValueError as e:
        raise UserError(str(e)) from None
    pipe = Pipeline(seg, calib.shaft_radius_m)
    total = _frame_count(src)
    counts = {"frames": 0, "accepted": 0, "rejected": 0}
    t0 = time.perf_counter()

    def items(messages) -> Iterator[tuple]:
        """("copy", schema, message) for what is copied, ("frame", k, message, camera) per frame."""
        camera: CameraModel | None = None
        k = 0
        for schema, channel, message in messages:
            topic = channel.topic
            if topic in FRAME_TOPICS:
                yield ("frame", k, (topic, message), camera)
                k += 1
            elif topic != "vision/observation":  # the bench's measurement-tier stand-in is replaced
                if topic == "camera/info":
                    camera = CameraModel.from_calibration(_camera_info(message.data))
                yield ("copy", schema, channel, message)

    def observe(item: tuple) -> vision_pb2.VisionObservation:
        _, k, (topic, message), camera = item
        if topic == COMPRESSED_TOPIC:
            compressed = CompressedImage.FromString(message.data)
            stamp = compressed.timestamp.ToNanoseconds()
        else:
            msg = RawImage.FromString(message.data)
            stamp = msg.timestamp.ToNanoseconds()
        try:
            if topic == COMPRESSED_TOPIC:
                try:
                    msg = decompress(compressed)
                except ValueError as e:
                    raise FrameError("bad_data", str(e)) from None
            if camera is None:
                raise FrameError("no_camera_info", "camera/image before any camera/info")
            obs = pipe.process(decode_frame(msg, camera), camera, stamp, k).obs
        except FrameError as e:
            obs = vision_pb2.VisionObservation(accepted=False, reject_reason=f"frame:{e.reason}")
            obs.header.stamp_ns, obs.header.seq = stamp, k
        obs.processed_stamp_ns = stamp + int(round(obs.processing_ms * 1e6))
        return obs

    with McapWriter(out) as w, Progress(sys.stderr, enabled=not quiet) as progress:
        for name, rec in read_metadata(src).items():
            w.add_metadata(name, rec)
        for res in ordered_map(observe, items(raw_messages(src)), workers, passthrough=lambda it: it[0] == "copy"):
            if isinstance(res, tuple):
                _, schema, channel, message = res
                w.write_raw(channel.topic, schema.name, message.data, message.log_time, message.publish_time,
                            message.sequence)  # fmt: skip
                continue
            k = counts["frames"]
            w.write("vision/observation", res, log_time_ns=res.header.stamp_ns, sequence=k)
            counts["frames"] += 1
            counts["accepted" if res.accepted else "rejected"] += 1
            dt = time.perf_counter() - t0
            progress.update(
                f"frame {k + 1}/{total or '?'}  {(k + 1) / max(dt, 1e-9):5.1f} frames/s  accepted {counts['accepted']}",
                force=k + 1 == total,
            )
    secs = time.perf_counter() - t0
    return {**counts, "seconds": secs, "fps": counts["frames"] / secs if secs > 0 else 0.0}


def _camera_info(data: bytes):
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration

    return CameraCalibration.FromString(data)
