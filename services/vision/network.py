"""The segmentation network: a U-Net with a ResNet-18 encoder, in plain torch (no torchvision).

Input: the whole frame area-downsampled by `NetSpec.step` (1280x720 -> 256x144), RGB scaled to
[0, 1] and normalised, padded at the bottom to a multiple of 32 rows. Output: one logit per
input pixel, the shaft (proximal of the junction). The encoder is ResNet-18 as published (He et
al. 2016: 7x7 stem, four stages of two basic blocks, 64-512 channels); the decoder is slim (at
most 128 channels) so the checkpoint stays under 25 MB in half precision and the whole pipeline
keeps up with 15 fps on two CPU cores.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class NetSpec:
    """Input geometry: full-frame size, the downsampling step, and the decoder's widths."""

    width: int = 1280
    height: int = 720
    step: int = 5
    decoder: tuple[int, int, int, int, int] = (128, 96, 64, 32, 16)

    @property
    def in_w(self) -> int:
        return self.width // self.step

    @property
    def in_h(self) -> int:
        return self.height // self.step

    @property
    def pad_h(self) -> int:
        return -self.in_h % 32

    @property
    def grid_offset(self) -> float:
        """Distorted full-resolution coordinate of grid pixel 0's centre (area average)."""
        return (self.step - 1) / 2.0


def conv3(cin: int, cout: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, stride, 1, bias=False)


class BasicBlock(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.conv1, self.bn1 = conv3(cin, cout, stride), nn.BatchNorm2d(cout)
        self.conv2, self.bn2 = conv3(cout, cout), nn.BatchNorm2d(cout)
        self.down = None
        if stride != 1 or cin != cout:
            self.down = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)), inplace=True)
        y = self.bn2(self.conv2(y))
        return F.relu(y + (x if self.down is None else self.down(x)), inplace=True)


class ResNet18Encoder(nn.Module):
    """Features at strides 2, 4, 8, 16, 32 with 64, 64, 128, 256, 512 channels."""

    def __init__(self) -> None:
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(3, 64, 7, 2, 3, bias=False), nn.BatchNorm2d(64), nn.ReLU(inplace=True))
        self.pool = nn.MaxPool2d(3, 2, 1)
        chans = [(64, 64, 1), (64, 128, 2), (128, 256, 2), (256, 512, 2)]
        self.layers = nn.ModuleList(nn.Sequential(BasicBlock(ci, co, s), BasicBlock(co, co, 1)) for ci, co, s in chans)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        f0 = self.stem(x)
        feats = [f0]
        y = self.pool(f0)
        for layer in self.layers:
            y = layer(y)
            feats.append(y)
        return feats


class UpBlock(nn.Module):
    def __init__(self, cin: int, cskip: int, cout: int):
        super().__init__()
        self.conv = nn.Sequential(conv3(cin + cskip, cout), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))

    def forward(self, x: torch.Tensor, skip: torch.Tensor | None) -> torch.Tensor:
        size = skip.shape[-2:] if skip is not None else (x.shape[-2] * 2, x.shape[-1] * 2)
        x = F.interpolate(x, size=size, mode="bilinear", align_corners=False)
        if skip is not None:
            x = torch.cat([x, skip], 1)
        return self.conv(x)


class ShaftUNet(nn.Module):
    """U-Net: ResNet-18 encoder, slim decoder, one logit per input pixel."""

    def __init__(self, spec: NetSpec | None = None):
        super().__init__()
        self.spec = spec or NetSpec()
        d = self.spec.decoder
        self.encoder = ResNet18Encoder()
        self.reduce = nn.Sequential(nn.Conv2d(512, d[0], 1, bias=False), nn.BatchNorm2d(d[0]), nn.ReLU(inplace=True))
        self.up = nn.ModuleList(
            [UpBlock(d[0], 256, d[1]), UpBlock(d[1], 128, d[2]), UpBlock(d[2], 64, d[3]), UpBlock(d[3], 64, d[4])]
        )
        self.last = UpBlock(d[4], 0, d[4])
        self.head = nn.Conv2d(d[4], 1, 1)
        # the shaft covers a few per cent of the frame: start from that prior, not from p = 0.5
        nn.init.constant_(self.head.bias, -3.0)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.encoder(x)
        y = self.reduce(f[4])
        for block, skip in zip(self.up, (f[3], f[2], f[1], f[0]), strict=True):
            y = block(y, skip)
        return self.head(self.last(y, None))


def preprocess(frames_rgb: np.ndarray | list[np.ndarray], spec: NetSpec) -> torch.Tensor:
    """Full frames (H, W, 3) uint8 -> normalised input batch (n, 3, in_h + pad, in_w) float32."""
    small = [downsample(f, spec) for f in (frames_rgb if isinstance(frames_rgb, list) else [frames_rgb])]
    return to_input(np.stack(small), spec)


def downsample(frame_rgb: np.ndarray, spec: NetSpec) -> np.ndarray:
    """(H, W, 3) uint8 full frame -> (in_h, in_w, 3) uint8, area average over step x step cells."""
    return cv2.resize(frame_rgb, (spec.in_w, spec.in_h), interpolation=cv2.INTER_AREA)


def to_input(small_rgb: np.ndarray, spec: NetSpec) -> torch.Tensor:
    """(n, in_h, in_w, 3) uint8 -> normalised, padded (n, 3, in_h + pad, in_w) float32 tensor."""
    x = torch.from_numpy(np.ascontiguousarray(small_rgb)).permute(0, 3, 1, 2).float().div_(255.0)
    mean = torch.tensor(MEAN).view(1, 3, 1, 1)
    std = torch.tensor(STD).view(1, 3, 1, 1)
    x = (x - mean) / std
    return F.pad(x, (0, 0, 0, spec.pad_h), mode="replicate") if spec.pad_h else x


def pick_device(name: str = "auto") -> torch.device:
    """'auto' -> CUDA when present, CPU otherwise; or 'cpu' / 'cuda' / 'cuda:N' as given."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"device {name!r} asked for but CUDA is not available here")
    if name != "cpu" and not name.startswith("cuda"):
        raise ValueError(f"device must be auto, cpu or cuda[:N] (got {name!r})")
    return torch.device(name)


class Segmenter:
    """A loaded network on a device: `probabilities(frame)` -> (in_h, in_w) float32 in [0, 1].

    Channels-last (NHWC) memory by default: oneDNN's convolutions run about 20 % faster on this
    CPU than on NCHW tensors (45 against 55 ms a frame, one thread); the probabilities differ
    from NCHW's by float rounding only (below 1e-5). Safe to call from several threads at
    once (inference only): `tiplog vision run` and the service overlap frames that way."""

    def __init__(self, model: ShaftUNet, device: torch.device, channels_last: bool = True):
        self.memory_format = torch.channels_last if channels_last else torch.contiguous_format
        self.model = model.to(device).to(memory_format=self.memory_format).eval()
        self.spec = model.spec
        self.device = device

    @torch.inference_mode()
    def probabilities(self, frame_rgb: np.ndarray) -> np.ndarray:
        x = preprocess(frame_rgb, self.spec).to(self.device).contiguous(memory_format=self.memory_format)
        logit = self.model(x)[0, 0, : self.spec.in_h]
        return torch.sigmoid(logit).float().cpu().numpy()


def save_checkpoint(path: str | Path, model: ShaftUNet, extra: dict | None = None, half: bool = True) -> None:
    """Weights (fp16 when `half`) with the spec and `extra` (training state, metrics)."""
    state = {k: (v.half() if half and v.is_floating_point() else v) for k, v in model.state_dict().items()}
    torch.save({"format": "tiplog-shaft-unet", "version": 1, "spec": asdict(model.spec), "state": state,
                "extra": extra or {}}, str(path))  # fmt: skip


def load_checkpoint(path: str | Path, device: str = "auto") -> tuple[Segmenter, dict]:
    """(Segmenter on the chosen device, the checkpoint's `extra`); ValueError naming the file
    when it is not a checkpoint of this network."""
    try:
        ck = torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as e:  # torch's unpickler raises many kinds (KeyError, UnpicklingError, ...) on junk
        raise ValueError(f"{path}: not a readable network checkpoint ({e.__class__.__name__})") from None
    if not isinstance(ck, dict) or ck.get("format") != "tiplog-shaft-unet":
        raise ValueError(f"{path}: not a tiplog shaft U-Net checkpoint")
    spec = NetSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in ck["spec"].items()})
    model = ShaftUNet(spec)
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in ck["state"].items()})
    return Segmenter(model, pick_device(device)), ck.get("extra", {})
