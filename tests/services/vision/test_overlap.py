"""Frames processed side by side give what one frame after another gives: results in order,
`tiplog vision run` with two workers byte-for-byte the same session as with one, and the
channels-last network within float rounding of the plain layout."""

from __future__ import annotations

import random
import threading

import numpy as np
import pytest
import torch

from services.vision import DEFAULT_WEIGHTS
from services.vision.network import Segmenter, load_checkpoint
from services.vision.overlap import InOrder, ordered_map
from services.vision.pipeline import Pipeline
from tests.services.vision.conftest import SHAFT_RADIUS_M
from tiplog.cli import main
from tiplog.mcap_io import read_messages


def test_ordered_map_keeps_the_order_and_passes_items_through():
    rng = random.Random(3)
    delays = {k: rng.random() * 0.004 for k in range(120)}
    seen_threads: set[str] = set()

    def slow_negate(k: int) -> int:
        seen_threads.add(threading.current_thread().name)
        threading.Event().wait(delays[k])  # finish out of order
        return -k

    items = list(range(120))
    want = [k if k % 4 == 0 else -k for k in items]
    got = list(ordered_map(slow_negate, items, workers=2, passthrough=lambda k: k % 4 == 0))
    assert got == want
    assert len(seen_threads) == 2 and all(n.startswith("vision") for n in seen_threads)
    assert list(ordered_map(slow_negate, items, workers=1, passthrough=lambda k: k % 4 == 0)) == want


def test_ordered_map_raises_at_the_failing_items_turn():
    def fn(k: int) -> int:
        if k == 5:
            raise ValueError("frame 5")
        return k

    out = []
    with pytest.raises(ValueError, match="frame 5"):
        for x in ordered_map(fn, range(20), workers=2):
            out.append(x)
    assert out == [0, 1, 2, 3, 4]


def test_in_order_tickets():
    order = InOrder()
    a, b = order.ticket(), order.ticket()
    assert order.wait_turn(a, 0.0) and not order.wait_turn(b, 0.01)
    order.done(a)
    assert order.wait_turn(b, 0.0)


def _strip_timing(o):
    o = type(o).FromString(o.SerializeToString())
    o.processing_ms, o.processed_stamp_ns = 0.0, 0
    return o


def test_vision_run_with_two_workers_is_the_same_session(recording, tmp_path):
    one, two = tmp_path / "one.mcap", tmp_path / "two.mcap"
    assert main(["vision", "run", str(recording), "--out", str(one), "--quiet", "--workers", "1"]) == 0
    assert main(["vision", "run", str(recording), "--out", str(two), "--quiet", "--workers", "2"]) == 0
    a, b = list(read_messages(one)), list(read_messages(two))
    assert [(r.topic, r.log_time_ns, r.sequence) for r in a] == [(r.topic, r.log_time_ns, r.sequence) for r in b]
    n_obs = 0
    for x, y in zip(a, b, strict=True):
        if x.topic == "vision/observation":
            assert _strip_timing(x.message) == _strip_timing(y.message)
            n_obs += 1
        else:
            assert x.message == y.message
    assert n_obs == 14  # the 1 s session's frames


def test_channels_last_network_matches_the_plain_layout(rendered, camera):
    """Tolerance: probabilities within 1e-4; observations the same but for float rounding, which
    can flip a mask pixel that sits at the 0.5 threshold: the mask's measures within 1e-3, the
    network's junction (found on the thresholded mask) within 0.05 px."""
    seg_cl, _ = load_checkpoint(DEFAULT_WEIGHTS, "cpu")
    assert seg_cl.memory_format == torch.channels_last
    seg_plain = Segmenter(load_checkpoint(DEFAULT_WEIGHTS, "cpu")[0].model, torch.device("cpu"), channels_last=False)
    for frame, _, _ in rendered:
        pa, pb = seg_cl.probabilities(frame), seg_plain.probabilities(frame)
        assert np.abs(pa - pb).max() < 1e-4
        oa = Pipeline(seg_cl, SHAFT_RADIUS_M).process(frame, camera, 1).obs
        ob = Pipeline(seg_plain, SHAFT_RADIUS_M).process(frame, camera, 1).obs
        assert (oa.accepted, oa.reject_reason, oa.junction_visible) == (
            ob.accepted,
            ob.reject_reason,
            ob.junction_visible,
        )
        for f in ("mask_iou", "line_angle_deg", "lateral_px"):
            assert getattr(oa, f) == pytest.approx(getattr(ob, f), abs=1e-3), f
        for f in ("junction_diff_px", "junction_u_px"):
            assert getattr(oa, f) == pytest.approx(getattr(ob, f), abs=0.05), f
        assert (oa.n_left.x, oa.n_left.y, oa.n_left.z) == (ob.n_left.x, ob.n_left.y, ob.n_left.z)  # labeler only
