"""`tiplog vision`: train the segmentation network; run the pipeline on a file."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="vision_command", metavar="ACTION", required=True)
    t = sub.add_parser("train", help="train the U-Net on labeler labels (CPU or GPU)")
    t.add_argument("sessions", nargs="+", help="MCAP sessions with camera/image")
    t.add_argument("--out", default="unet.pt", help="weights file to write")
    t.add_argument("--epochs", type=int, default=60)
    t.add_argument("--device", default="auto", help="auto, cpu or cuda")
    t.set_defaults(func=not_yet("network training", "the vision issue"))
    r = sub.add_parser("run", help="run the vision pipeline over the frames of a recording")
    r.add_argument("recording")
    r.add_argument("--out", required=True, help="MCAP file with vision/observation")
    r.set_defaults(func=not_yet("offline vision", "the vision issue"))
