"""`tiplog vision`: train the segmentation network on labeler labels; run the pipeline on a file."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from services.vision import DEFAULT_WEIGHTS
from tiplog.userio import UserError, atomic_output, input_file, input_mcap, output_file

log = logging.getLogger(__name__)


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="vision_command", metavar="ACTION", required=True)
    t = sub.add_parser("train", help="train the U-Net on labeler labels of recordings (CPU or GPU)")
    t.add_argument("sessions", nargs="+", help="MCAP recordings with camera/image and camera/info")
    t.add_argument("--out", required=True, help="checkpoint to write (half precision)")
    t.add_argument("--epochs", type=int, default=4)
    t.add_argument("--batch", type=int, default=8, help="frames per step, half of them synthetic composites")
    t.add_argument("--lr", type=float, default=3e-4)
    t.add_argument("--every", type=int, default=3, help="use every N-th frame of each recording")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--input-step", type=int, default=5, help="the network sees the frame downsampled this many times")
    t.add_argument("--device", default="auto", help="auto, cpu or cuda")
    t.add_argument("--threads", type=int, default=0, help="CPU threads for torch (0: torch's default)")
    t.add_argument("--resume", action="store_true", help="continue from <out>.resume")
    t.add_argument("--force", action="store_true", help="overwrite an existing checkpoint")
    t.set_defaults(func=_train)
    r = sub.add_parser("run", help="run the vision pipeline over the frames of a recording")
    r.add_argument("recording")
    r.add_argument("--out", required=True, help="MCAP file with vision/observation")
    r.add_argument("--weights", help=f"network checkpoint (default {DEFAULT_WEIGHTS.name} shipped in models/)")
    r.add_argument("--calibration", help="calibration YAML (default: the recording's own metadata)")
    r.add_argument("--device", default="cpu", help="auto, cpu or cuda (cpu is deterministic)")
    r.add_argument("--threads", type=int, default=1, help="CPU threads for torch, per worker")
    r.add_argument("--workers", type=int, default=2, help="frames processed side by side (same output for any number)")
    r.add_argument("--force", action="store_true", help="overwrite an existing output file")
    r.add_argument("--quiet", action="store_true", help="no progress on stderr")
    r.set_defaults(func=_run)


def _positive(name: str, v: float) -> None:
    if not v > 0:
        raise UserError(f"--{name.replace('_', '-')} must be positive (got {v})")


def _train(args: argparse.Namespace) -> int:
    import torch

    from services.vision.dataset import label_recordings
    from services.vision.network import NetSpec, pick_device, save_checkpoint
    from services.vision.train import TrainOptions, train

    for name in ("epochs", "batch", "lr", "every", "input_step"):
        _positive(name, getattr(args, name))
    if args.batch < 2:
        raise UserError("--batch must be at least 2 (half real frames, half composites)")
    paths = [input_mcap(s) for s in args.sessions]
    output_file(args.out, args.force or args.resume)
    try:
        device = pick_device(args.device)
    except ValueError as e:
        raise UserError(f"--device: {e}") from None
    if args.threads:
        torch.set_num_threads(args.threads)

    def say(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    try:
        spec = NetSpec(step=args.input_step)
        frames = label_recordings(paths, spec, every=args.every, progress=say)
    except ValueError as e:
        raise UserError(str(e)) from None

    def write(path: Path, model, metrics: dict) -> None:
        with atomic_output(path, force=True) as tmp:
            save_checkpoint(tmp, model, {"metrics": metrics, "sessions": [p.name for p in paths]})

    opts = TrainOptions(args.epochs, args.batch, args.lr, args.seed, 0.25, str(device))
    metrics = train(frames, args.out, opts, spec=spec, resume=args.resume, progress=say, write=write)
    say(f"wrote {args.out}: held-out IoU {metrics['held_out_iou'][-1]:.4f} after {metrics['epochs']} epochs "
        f"({metrics['train_frames']} training / {metrics['held_out_frames']} held-out frames, {metrics['seconds']} s)")  # fmt: skip
    return 0


def _run(args: argparse.Namespace) -> int:
    from services.vision.offline import run_file

    src = input_mcap(args.recording)
    weights = input_file(args.weights or DEFAULT_WEIGHTS, "network checkpoint")
    calib = input_file(args.calibration, "calibration file") if args.calibration else None
    if args.workers < 1:
        raise UserError(f"--workers must be at least 1 (got {args.workers})")
    with atomic_output(args.out, args.force) as tmp:
        summary = run_file(src, tmp, weights, calib, args.device, args.threads, args.quiet, args.workers)
    print(
        f"{args.out}: {summary['frames']} frames, {summary['accepted']} accepted, {summary['rejected']} rejected "
        f"in {summary['seconds']:.1f} s ({summary['fps']:.1f} frames/s)",
        file=sys.stderr,
    )
    return 0
