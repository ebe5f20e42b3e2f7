"""`tiplog export FORMAT RECORDING.mcap --out PATH`: the fused estimate for other tools.

Formats: `lerobot` (a LeRobot v3.0 dataset folder), `slicer` (a PLUS / 3D Slicer sequence
file, `.seq.mha`), `csv` (JIGSAWS-style kinematics). The states come from `--estimate` (a
`tiplog fusion run` file) or else from the recording itself (fusion/state_settled, else
fusion/state). Nothing is written unless the whole export succeeds; an existing output is
replaced only with `--force`.
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from tiplog.calibration import Calibration, CalibrationError
from tiplog.export import track as tr
from tiplog.mcap_io import read_metadata
from tiplog.userio import UserError, atomic_output, input_file, input_mcap

log = logging.getLogger("tiplog.export")
FORMATS = ("lerobot", "slicer", "csv")


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("format", choices=FORMATS, help="lerobot (dataset folder), slicer (.seq.mha), csv (JIGSAWS-style)")
    p.add_argument("recording", metavar="RECORDING.mcap", help="a recording or bench session")
    p.add_argument("--out", required=True, metavar="PATH", help="the dataset folder (lerobot) or file to write")
    p.add_argument("--estimate", metavar="EST.mcap", help="states from this `tiplog fusion run` file instead")
    p.add_argument(
        "--segments",
        choices=tr.SEGMENTS,
        default="whole",
        help="whole: one segment; events: cut at the recorder's event marks (one LeRobot episode each)",
    )
    p.add_argument("--fps", type=float, default=30.0, help="frame grid [Hz] (default 30; slicer/csv: 0 = every state)")
    p.add_argument("--task", default="hand-held laparoscopic instrument motion", help="lerobot: the episodes' task")
    p.add_argument(
        "--no-video",
        action="store_true",
        help="lerobot: leave out the recording's images (vision/preview, camera/image)",
    )
    p.add_argument(
        "--calibration", metavar="FILE", help="slicer: calibration for TrocarToReference (default: the recording's)"
    )
    p.add_argument("--force", action="store_true", help="replace an existing output")
    p.set_defaults(func=run)


def _given_rcm(args: argparse.Namespace) -> np.ndarray | None:
    """The RCM of `--calibration`, checked before anything is read."""
    if not args.calibration:
        return None
    try:
        return Calibration.load_yaml(input_file(args.calibration, "calibration file")).rcm_base_m
    except CalibrationError as e:
        raise UserError(str(e)) from None
    except UnicodeDecodeError:
        raise UserError(f"{args.calibration}: not a calibration file (not text)") from None


def _rcm(recording: Path, estimate: Path | None) -> np.ndarray | None:
    for source in (recording, estimate):
        if source is None:
            continue
        md = read_metadata(source)
        if "fusion_calibration" in md:  # what `tiplog fusion run` used
            md = {"calibration": md["fusion_calibration"], **md}
        try:
            return Calibration.from_mcap_metadata(md, where=str(source)).rcm_base_m
        except CalibrationError:
            continue
    log.warning("no calibration in %s: TrocarToReference is not written", recording)
    return None


def _check_estimate_of(recording: Path, estimate: Path) -> None:
    """UserError when `estimate` is a `tiplog fusion run` of another recording (its recorded
    source fingerprint, else its source's name, differs)."""
    from services.fusion.offline.inputs import source_fingerprint

    made = read_metadata(estimate).get("fusion", {})
    want = made.get("source_fingerprint")
    if want and want != source_fingerprint(recording):
        raise UserError(
            f"{estimate}: an estimate of another recording ({made.get('source', '?')}), not of {recording.name}"
        )
    if not want and made.get("source") and made["source"] != recording.name:
        raise UserError(f"{estimate}: an estimate of {made['source']}, not of {recording.name}")


def _check_out_dir(out: Path, force: bool) -> None:
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise UserError(f"{out}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise UserError(f"{out}: folder {parent} is not writable")
    if out.exists() and not force:
        raise UserError(f"{out}: exists, use --force to replace it")
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: not a folder; a LeRobot dataset is a folder")


def _lerobot(
    args: argparse.Namespace, recording: Path, out: Path, track: tr.Track, segments: list[tr.Frames], fps: float
) -> str:
    from tiplog.export.lerobot import write_dataset
    from tiplog.export.video import image_topics

    if fps != int(fps) or fps <= 0:
        raise UserError(f"--fps {args.fps}: a LeRobot dataset needs a whole positive frame rate")
    _check_out_dir(out, args.force)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    try:
        images = [] if args.no_video else image_topics(recording)
        counts = write_dataset(tmp, track, segments, int(fps), args.task, recording, images)
        if counts["frames"] == 0:
            raise UserError("nothing to export: no stretch of two or more frames with a fusion state")
        _check_out_dir(out, args.force)
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    videos = f", {counts['videos']} video(s)" if counts["videos"] else ""
    return f"{counts['episodes']} episode(s), {counts['frames']} frames at {int(fps)} fps{videos}"


def run(args: argparse.Namespace) -> int:
    recording = input_mcap(args.recording)
    estimate = input_mcap(args.estimate) if args.estimate else None
    given_rcm = _given_rcm(args)
    out = Path(args.out)
    if not np.isfinite(args.fps) or args.fps < 0 or args.fps > 1000:
        raise UserError(f"--fps {args.fps}: must be between 0 and 1000")
    if args.format != "lerobot":  # refused before any reading
        from tiplog.userio import output_file

        output_file(out, args.force)
    else:
        _check_out_dir(out, args.force)
    if estimate is not None:
        _check_estimate_of(recording, estimate)
    track = tr.load_track(recording, estimate)
    bounds = tr.segment_bounds(track, recording, args.segments)
    segments = tr.frames(track, bounds, args.fps)
    if not segments:
        raise UserError("nothing to export: no segment holds two fusion states")
    if args.format == "lerobot":
        what = _lerobot(args, recording, out, track, segments, args.fps)
    elif args.format == "slicer":
        from tiplog.export.slicer import write_sequence

        rcm = given_rcm if given_rcm is not None else _rcm(recording, estimate)
        with atomic_output(out, args.force) as tmp:
            n = write_sequence(tmp, track, segments, rcm, tr.provenance(track, recording))
        what = f"{n} frames"
    else:
        from tiplog.export.jigsaws import write_csv

        with atomic_output(out, args.force) as tmp:
            n = write_csv(tmp, track, segments)
        what = f"{n} rows"
    print(f"{out}: {what} from {track.topic} of {track.source.name} ({len(segments)} segment(s))")
    return 0
