"""The U-Net: shapes, checkpoints, determinism on the CPU, CPU/GPU agreement."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from services.vision import DEFAULT_WEIGHTS
from services.vision.network import NetSpec, Segmenter, ShaftUNet, load_checkpoint, pick_device, save_checkpoint

SMALL = NetSpec(width=320, height=180, step=5)  # 64x36 input: fast


def _frame(seed: int = 0, spec: NetSpec = SMALL) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (spec.height, spec.width, 3), dtype=np.uint8)


def test_resnet18_encoder_and_output_shape():
    torch.manual_seed(0)
    model = ShaftUNet(SMALL)
    enc = sum(p.numel() for p in model.encoder.parameters())
    assert 11.1e6 < enc < 11.2e6  # ResNet-18 without its classifier: 11.18 M
    prob = Segmenter(model, torch.device("cpu")).probabilities(_frame())
    assert prob.shape == (SMALL.in_h, SMALL.in_w) and prob.dtype == np.float32
    assert np.all((prob >= 0) & (prob <= 1))


def test_checkpoint_round_trip_in_half_precision(tmp_path):
    torch.manual_seed(1)
    model = ShaftUNet(SMALL)
    with torch.no_grad():  # non-trivial batch-norm statistics
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.1, 0.1)
                m.running_var.uniform_(0.5, 1.5)
    path = tmp_path / "net.pt"
    save_checkpoint(path, model, {"metrics": {"held_out_iou": [0.5]}})
    seg, extra = load_checkpoint(path, "cpu")
    assert seg.spec == SMALL and extra["metrics"]["held_out_iou"] == [0.5]
    a = Segmenter(model, torch.device("cpu")).probabilities(_frame(2))
    b = seg.probabilities(_frame(2))
    assert np.abs(a - b).max() < 2e-2  # fp16 weights


def test_not_a_checkpoint_is_named(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="bad.pt"):
        load_checkpoint(bad, "cpu")
    torch.save({"format": "something else"}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a tiplog shaft U-Net"):
        load_checkpoint(tmp_path / "other.pt", "cpu")


def test_device_names():
    assert pick_device("cpu").type == "cpu"
    with pytest.raises(ValueError, match="device must be"):
        pick_device("tpu")


def test_shipped_checkpoint_is_small_and_deterministic_on_cpu():
    assert DEFAULT_WEIGHTS.stat().st_size <= 25 * 2**20
    seg, extra = load_checkpoint(DEFAULT_WEIGHTS, "cpu")
    assert extra["metrics"]["held_out_iou"][-1] > 0.8
    f = _frame(3, seg.spec)
    assert np.array_equal(seg.probabilities(f), seg.probabilities(f))


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_and_cpu_agree(rendered):
    """Same checkpoint on both devices: probabilities within 0.02, masks (p > 0.5) IoU > 0.99."""
    cpu, _ = load_checkpoint(DEFAULT_WEIGHTS, "cpu")
    gpu, _ = load_checkpoint(DEFAULT_WEIGHTS, "cuda")
    for img, _truth, _T in rendered:
        a, b = cpu.probabilities(img), gpu.probabilities(img)
        assert np.abs(a - b).max() < 0.02
        ma, mb = a > 0.5, b > 0.5
        assert (ma & mb).sum() / max((ma | mb).sum(), 1) > 0.99
