"""What archiving the camera costs: CPU per 1280x720 frame (one thread) and bytes per frame,
as hours of case per disk, for raw frames, JPEG (OpenCV, the recorder's default) at a few
qualities and H.264 (PyAV / libx264, CompressedVideo's codec) at a few presets, on the frames
of a recording (a pixel-tier session: `tiplog sim generate --tier pixel`).

    python -m benchmarks.camera_archive FILE [--frames 150] [--fps 30]

H.264 needs PyAV (`pip install av`); without it those rows say so.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from fractions import Fraction

import cv2
import numpy as np

from tiplog.mcap_io import read_messages

GiB = 2**30


def _frames(path: str, n: int) -> list[np.ndarray]:
    from services.vision.frames import decode_frame

    out = []
    for rec in read_messages(path, ["camera/image"]):
        out.append(decode_frame(rec.message, None))
        if len(out) >= n:
            break
    if not out:
        raise SystemExit(f"{path}: no camera/image frames (record a pixel-tier session)")
    return out


def _jpeg(quality: int) -> Callable[[list[np.ndarray]], list[int]]:
    def run(frames: list[np.ndarray]) -> list[int]:
        sizes = []
        for f in frames:
            ok, buf = cv2.imencode(".jpg", cv2.cvtColor(f, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
            sizes.append(len(buf))
        return sizes

    return run


def _h264(preset: str, crf: int, fps: int) -> Callable[[list[np.ndarray]], list[int]]:
    def run(frames: list[np.ndarray]) -> list[int]:
        import av

        h, w = frames[0].shape[:2]
        codec = av.CodecContext.create("libx264", "w")
        codec.width, codec.height, codec.pix_fmt = w, h, "yuv420p"
        codec.time_base = Fraction(1, fps)
        codec.options = {"preset": preset, "crf": str(crf), "tune": "zerolatency", "g": str(fps)}
        codec.thread_count = 1
        sizes = []
        for k, f in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(f, format="rgb24").reformat(format="yuv420p")
            frame.pts = k
            sizes.append(sum(p.size for p in codec.encode(frame)))
        sizes[-1] += sum(p.size for p in codec.encode(None))
        return sizes

    return run


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file")
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--fps", type=int, default=30, help="camera frame rate the archive is sized for")
    ap.add_argument("--disk-gib", type=float, default=200.0, help="free disk the hours are given for")
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    frames = _frames(a.file, a.frames)
    h, w = frames[0].shape[:2]
    rows: list[tuple[str, float, float]] = [("raw rgb8", 0.0, float(w * h * 3))]
    encoders = {f"jpeg q{q}": _jpeg(q) for q in (95, 90, 80)}
    encoders |= {f"h264 {p} crf23": _h264(p, 23, a.fps) for p in ("ultrafast", "veryfast")}
    for name, enc in encoders.items():
        try:
            t = time.process_time()
            sizes = enc(frames)
            cpu_ms = (time.process_time() - t) * 1e3 / len(frames)
        except ImportError as e:
            print(f"{name}: not measured ({e})")
            continue
        rows.append((name, cpu_ms, float(np.mean(sizes))))
    print(f"{len(frames)} frames {w}x{h} from {a.file}, one thread, sized at {a.fps} frames/s")
    print(f"{'archive':<22}{'CPU ms/frame':>13}{'% of a core':>12}{'KiB/frame':>11}{'GB/hour':>9}{'hours/disk':>11}")
    for name, cpu_ms, size in rows:
        per_hour = size * a.fps * 3600
        print(
            f"{name:<22}{cpu_ms:>13.2f}{cpu_ms * a.fps / 10:>12.1f}{size / 1024:>11.1f}"
            f"{per_hour / 1e9:>9.2f}{a.disk_gib * GiB / per_hour:>11.1f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
