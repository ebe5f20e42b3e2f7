"""Training the shaft U-Net on labeler labels (paper: Adam 3e-4, half of each batch synthetic
composites, a quarter of the poses held out). Seeded and resumable: the full-precision state
(weights, optimiser, epoch, generators) is kept beside the checkpoint as `<out>.resume` after
every epoch; the checkpoint itself (half precision) is what the service loads."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from services.vision.dataset import LabeledFrames, backgrounds, composite, split_by_pose
from services.vision.network import NetSpec, ShaftUNet, save_checkpoint, to_input
from tiplog.userio import UserError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainOptions:
    epochs: int = 4
    batch: int = 8  # half real frames, half composites
    lr: float = 3e-4
    seed: int = 0
    held_out: float = 0.25
    device: str = "cpu"


def _loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy plus soft Dice (the mask is a thin band: Dice keeps it from vanishing)."""
    bce = F.binary_cross_entropy_with_logits(logits, target)
    p = torch.sigmoid(logits)
    inter = (p * target).sum((1, 2, 3))
    dice = 1.0 - (2.0 * inter + 1.0) / (p.sum((1, 2, 3)) + target.sum((1, 2, 3)) + 1.0)
    return bce + dice.mean()


@torch.inference_mode()
def held_out_iou(model: ShaftUNet, frames: LabeledFrames, idx: np.ndarray, device: torch.device) -> float:
    """Mean IoU of the network's mask (p > 0.5) against the labels on the held-out frames."""
    model.eval()
    ious = []
    for i0 in range(0, len(idx), 16):
        sel = idx[i0 : i0 + 16]
        x = to_input(frames.images[sel], model.spec).to(device)
        pred = (model(x)[:, 0, : model.spec.in_h] > 0).cpu().numpy()
        lab = frames.masks[sel].astype(bool)
        inter = (pred & lab).sum((1, 2))
        union = (pred | lab).sum((1, 2))
        ious.extend((inter / np.maximum(union, 1)).tolist())
    model.train()
    return float(np.mean(ious)) if ious else float("nan")


def _batch(frames, bgs, train_idx, rng, n, spec):
    half = n // 2
    real = rng.choice(train_idx, half)
    imgs = [frames.images[i] for i in real]
    masks = [frames.masks[i] for i in real]
    for _ in range(n - half):
        i_fg, i_bg = rng.choice(train_idx, 2)
        img, m = composite(frames, bgs, int(i_fg), int(i_bg), rng)
        imgs.append(img)
        masks.append(m)
    flip = rng.random(n) < 0.5
    imgs = [im[:, ::-1] if f else im for im, f in zip(imgs, flip, strict=True)]
    masks = [m[:, ::-1] if f else m for m, f in zip(masks, flip, strict=True)]
    x = to_input(np.stack(imgs), spec)
    y = torch.from_numpy(np.ascontiguousarray(np.stack(masks))).float()[:, None]
    y = F.pad(y, (0, 0, 0, spec.pad_h)) if spec.pad_h else y
    return x, y


def train(
    frames: LabeledFrames,
    out: str | Path,
    opts: TrainOptions,
    spec: NetSpec | None = None,
    resume: bool = False,
    progress: Callable[[str], None] | None = None,
    write: Callable[[Path, ShaftUNet, dict], None] | None = None,
) -> dict:
    """Train, write the checkpoint to `out` (through `write` when given) and return the metrics:
    held-out IoU per epoch, frame counts, seconds."""
    say = progress or (lambda s: None)
    torch.manual_seed(opts.seed)
    rng = np.random.default_rng(opts.seed)
    device = torch.device(opts.device)
    spec = spec or NetSpec()
    model = ShaftUNet(spec).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=opts.lr)
    train_idx, test_idx = split_by_pose(frames, opts.held_out, salt=str(opts.seed))
    state_path = Path(str(out) + ".resume")
    history: list[float] = []
    start = 0
    if resume and state_path.exists():
        try:
            st = torch.load(state_path, map_location="cpu", weights_only=False)
            model.load_state_dict(st["model"])
            opt.load_state_dict(st["optim"])
            start, history = int(st["epoch"]), list(st["history"])
            rng.bit_generator.state = st["rng"]
            torch.set_rng_state(st["torch_rng"])
        except Exception as e:  # noqa: BLE001 - a cut, foreign or mismatched file (another --input-step)
            raise UserError(
                f"{state_path}: not a training state this run can continue ({type(e).__name__}); "
                "delete it, or train without --resume"
            ) from None
        say(f"resumed after epoch {start} from {state_path}")
    say(f"{len(train_idx)} training frames, {len(test_idx)} held out (by pose); batch {opts.batch}, half composites")
    bgs = backgrounds(frames)
    steps = max(1, int(np.ceil(2 * len(train_idx) / opts.batch)))
    t0 = time.perf_counter()
    model.train()
    for epoch in range(start, opts.epochs):
        running = 0.0
        for s in range(steps):
            x, y = _batch(frames, bgs, train_idx, rng, opts.batch, spec)
            loss = _loss(model(x.to(device)), y.to(device))
            opt.zero_grad()
            loss.backward()
            opt.step()
            running += loss.item()
            if (s + 1) % 10 == 0 or s + 1 == steps:
                say(f"epoch {epoch + 1}/{opts.epochs} step {s + 1}/{steps} loss {running / (s + 1):.4f} "
                    f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip
        iou = held_out_iou(model, frames, test_idx, device)
        history.append(iou)
        say(f"epoch {epoch + 1}/{opts.epochs}: held-out IoU {iou:.4f}")
        torch.save({"model": model.state_dict(), "optim": opt.state_dict(), "epoch": epoch + 1, "history": history,
                    "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state()}, state_path)  # fmt: skip
    metrics = {
        "held_out_iou": history,
        "train_frames": int(len(train_idx)),
        "held_out_frames": int(len(test_idx)),
        "epochs": opts.epochs,
        "batch": opts.batch,
        "lr": opts.lr,
        "seed": opts.seed,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    model.cpu()
    if write is not None:
        write(Path(out), model, metrics)
    else:
        save_checkpoint(out, model, {"metrics": metrics})
    return metrics
