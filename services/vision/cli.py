"""`tiplog vision`: train the segmentation network on labeler labels; run the pipeline on a file."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import zipfile
from pathlib import Path

from services.vision import DEFAULT_WEIGHTS
from tiplog.cliargs import finite, whole
from tiplog.userio import UserError, atomic_output, input_file, input_mcap, output_file

log = logging.getLogger(__name__)


# The network sees the frame downsampled `--input-step` times; past 720 / 32 = 22 the frame is
# less than one cell of the U-Net's coarsest level (stride 32) tall, and past 720 it is empty.
MAX_INPUT_STEP = 22
# torch threads and frame workers: beyond a few per core they only cost memory (100000 threads
# crashed the process, 5000 stalled it for minutes)
MAX_THREADS = 4 * (os.cpu_count() or 1)


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="vision_command", metavar="ACTION", required=True)
    t = sub.add_parser("train", help="train the U-Net on labeler labels of recordings (CPU or GPU)")
    t.add_argument("sessions", nargs="+", help="MCAP recordings with camera/image and camera/info")
    t.add_argument("--out", required=True, help="checkpoint to write (half precision)")
    t.add_argument("--epochs", type=whole(1), default=4)
    t.add_argument(
        "--batch", type=whole(2), default=8, help="frames per step, 2 or more: half of them synthetic composites"
    )
    t.add_argument("--lr", type=finite(0, lo_open=True), default=3e-4, help="Adam's learning rate (> 0)")
    t.add_argument("--every", type=whole(1), default=3, help="use every N-th frame of each recording")
    t.add_argument("--seed", type=whole(0), default=0)
    t.add_argument(
        "--input-step",
        type=whole(1, MAX_INPUT_STEP),
        default=5,
        help=f"the network sees the frame downsampled this many times (1-{MAX_INPUT_STEP})",
    )
    t.add_argument("--device", default="auto", help="auto, cpu or cuda")
    t.add_argument(
        "--threads", type=whole(0, MAX_THREADS), default=0, help="CPU threads for torch (0: torch's default)"
    )
    t.add_argument(
        "--resume",
        action="store_true",
        help="continue from <out>.resume (written after every epoch), replacing <out>; without it, start afresh",
    )
    t.add_argument("--force", action="store_true", help="overwrite an existing checkpoint")
    t.set_defaults(func=_train)
    r = sub.add_parser("run", help="run the vision pipeline over the frames of a recording")
    r.add_argument("recording")
    r.add_argument("--out", required=True, help="MCAP file with vision/observation")
    r.add_argument("--weights", help=f"network checkpoint (default {DEFAULT_WEIGHTS.name} shipped in models/)")
    r.add_argument("--calibration", help="calibration YAML (default: the recording's own metadata)")
    r.add_argument("--device", default="cpu", help="auto, cpu or cuda (cpu is deterministic)")
    r.add_argument(
        "--threads",
        type=whole(0, MAX_THREADS),
        default=1,
        help=f"CPU threads for torch, per worker (0: torch's default; at most {MAX_THREADS} here)",
    )
    r.add_argument(
        "--workers",
        type=whole(1, MAX_THREADS),
        default=2,
        help="frames processed side by side (same output for any number)",
    )
    r.add_argument("--force", action="store_true", help="overwrite an existing output file")
    r.add_argument("--quiet", action="store_true", help="no progress on stderr")
    r.set_defaults(func=_run)


def _train(args: argparse.Namespace) -> int:
    import torch

    from services.vision.dataset import label_recordings
    from services.vision.network import NetSpec, pick_device, save_checkpoint
    from services.vision.train import TrainOptions, train

    paths = [input_mcap(s) for s in args.sessions]
    state = Path(str(args.out) + ".resume")
    resuming = args.resume and state.exists()
    if resuming and not zipfile.is_zipfile(state):  # torch.save writes a zip; a cut one has no directory
        raise UserError(f"{state}: not a readable training state (cut short?); delete it, or train without --resume")
    # Resuming replaces the checkpoint of the training it continues; anything else needs --force.
    output_file(args.out, args.force or resuming)
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
    if len(frames) < 2:
        raise UserError(
            f"--every {args.every}: {len(frames)} labelled frame(s); training needs at least 2 (one trained on, "
            "one held out): lower --every or give more recordings"
        )

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
    with atomic_output(args.out, args.force) as tmp:
        summary = run_file(src, tmp, weights, calib, args.device, args.threads, args.quiet, args.workers)
    print(
        f"{args.out}: {summary['frames']} frames, {summary['accepted']} accepted, {summary['rejected']} rejected "
        f"in {summary['seconds']:.1f} s ({summary['fps']:.1f} frames/s)",
        file=sys.stderr,
    )
    return 0
