"""`tiplog calibrate intrinsics IMAGES --board 9x6 --square-mm 25`: the camera's intrinsics
and distortion from chessboard views: a folder of images (png, jpg, bmp; sorted by name) or an
MCAP recording with `camera/image` (foxglove.RawImage, rgb8/bgr8/mono8; every --every-th frame).
The last --heldout views that show the board are scored, not fitted.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import yaml

from tiplog.calibration import Calibration, CalibrationError
from tiplog.calibration.fits.intrinsics import find_corners, fit_intrinsics
from tiplog.cliargs import finite, whole
from tiplog.mcap_io import read_messages
from tiplog.userio import UserError, atomic_output, input_file, input_mcap, output_file, register_input

EXTS = (".png", ".jpg", ".jpeg", ".bmp")
MIN_FIT_VIEWS = 5  # fit_intrinsics' minimum


def _board(text: str) -> tuple[int, int]:
    try:
        c, r = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise UserError(f"--board: expected COLSxROWS inner corners, e.g. 9x6 (got {text!r})") from None
    if c < 3 or r < 3:
        raise UserError(f"--board: needs at least 3x3 inner corners (got {text!r})")
    return c, r


def _gray_from_raw(m) -> np.ndarray:
    ch = {"rgb8": 3, "bgr8": 3, "mono8": 1}.get(m.encoding)
    if ch is None:
        raise UserError(f"camera/image: unsupported encoding {m.encoding!r} (rgb8, bgr8, mono8)")
    a = np.frombuffer(m.data, np.uint8).reshape(m.height, m.step)[:, : m.width * ch].reshape(m.height, m.width, ch)
    if ch == 1:
        return a[:, :, 0].copy()
    return cv2.cvtColor(a, cv2.COLOR_RGB2GRAY if m.encoding == "rgb8" else cv2.COLOR_BGR2GRAY)


def image_source(source: str | Path, every: int = 1) -> list[Path] | Path:
    """The image files a folder gives (sorted by name, every `every`-th) or the MCAP file, each
    registered as an input (--out may not replace one); UserError when there is none."""
    p = Path(source)
    if not p.exists():
        raise UserError(f"{p}: no such folder or MCAP file")
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.suffix.lower() in EXTS)
        if not files:
            raise UserError(f"{p}: no image files ({', '.join(EXTS)}) in the folder")
        for f in files[::every]:
            register_input(f, "chessboard image")
        return files[::every]
    return input_mcap(p)


def iter_gray(source: str | Path, every: int = 1) -> Iterator[np.ndarray]:
    """8-bit grey images from a folder of image files or an MCAP file's camera/image."""
    src = image_source(source, every)
    if isinstance(src, list):
        for f in src:
            img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
            if img is None:
                raise UserError(f"{f}: not a readable image")
            yield img
        return
    for k, rec in enumerate(read_messages(src, ["camera/image"])):
        if k % every == 0:
            yield _gray_from_raw(rec.message)


def run(args: argparse.Namespace) -> int:
    cols, rows = _board(args.board)
    # the inputs first, then --out, which must not be one of them: refused before any work
    image_source(args.images, args.every)
    base_file = input_file(args.base, "calibration file") if args.base else None
    output_file(args.out, args.force)
    base = None
    if base_file is not None:
        try:
            base = Calibration.load_yaml(base_file)
        except CalibrationError as e:
            raise UserError(str(e)) from None
    corners, size, seen = [], None, 0
    for gray in iter_gray(args.images, args.every):
        seen += 1
        size = (gray.shape[1], gray.shape[0])
        c = find_corners(gray, cols, rows)
        if c is not None:
            corners.append(c)
    if size is None:
        raise UserError(f"{args.images}: no camera images")
    if args.heldout and len(corners) - args.heldout < MIN_FIT_VIEWS:
        raise UserError(
            f"--heldout {args.heldout} leaves {max(len(corners) - args.heldout, 0)} of the {len(corners)} views "
            f"showing the whole board to fit (need at least {MIN_FIT_VIEWS})"
        )
    res = fit_intrinsics(corners, size, cols, rows, args.square_mm * 1e-3, heldout=args.heldout)
    report = {
        "images": seen,
        "views_with_board": len(corners),
        "fit_rms_px": round(res.fit_rms_px, 4),
        "heldout_rms_px": round(res.heldout_rms_px, 4),
        "heldout_views": res.heldout_views,
        "largest_board_tilt_deg": round(res.tilt_spread_deg, 1),
    }
    with atomic_output(args.out, args.force) as tmp:
        if base is not None:
            dataclasses.replace(base, intrinsics=res.as_dict()).save_yaml(tmp, extra={"intrinsics": report})
        else:
            doc = {"intrinsics": {**res.as_dict(), "width": res.width, "height": res.height}, "report": report}
            tmp.write_text(yaml.safe_dump(doc, sort_keys=False))
    sys.stdout.write(yaml.safe_dump({**res.as_dict(), **report}, sort_keys=False))
    sys.stdout.write(f"wrote {args.out}\n")
    return 0


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("images", help="folder of chessboard images, or an MCAP file with camera/image")
    p.add_argument("--board", default="9x6", help="inner corners COLSxROWS (default 9x6)")
    p.add_argument("--square-mm", type=finite(0, 1000, lo_open=True), default=25.0, help="side of one square [mm]")
    p.add_argument(
        "--heldout",
        type=whole(0),
        default=0,
        metavar="N",
        help="score the last N views with a board instead of fitting them",
    )
    p.add_argument("--every", type=whole(1), default=1, metavar="N", help="use every N-th image")
    p.add_argument("--out", required=True, help="YAML to write: a calibration file with --base, else the result alone")
    p.add_argument("--base", help="calibration file whose intrinsics the result replaces")
    p.add_argument("--force", action="store_true", help="overwrite --out")
    p.set_defaults(func=run)
