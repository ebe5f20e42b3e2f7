"""The vision benchmarks stay runnable (their figures come from running them in full)."""

from __future__ import annotations

import json

import pytest

from tiplog.mcap_io import read_messages

pytestmark = pytest.mark.slow


def test_frame_benchmark_runs(recording, tmp_path):
    from benchmarks import vision_frame

    out = tmp_path / "frame.json"
    assert vision_frame.main(["--recording", str(recording), "--frames", "4", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["frames_timed"] == 4 and r["per_frame"]["total_ms"]["p50"] > 0
    frames = sum(1 for _ in read_messages(recording, ["camera/image"]))
    assert r["vision_run"]["frames"] == frames and r["vision_run"]["fps"] > 0


def test_accuracy_benchmark_runs(tmp_path):
    from benchmarks import vision_accuracy

    out = tmp_path / "acc.json"
    assert vision_accuracy.main(["--scenario", "demo", "--seeds", "1001", "--duration", "0.5", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    for tier in ("pixel", "model"):
        s = r["pooled"][tier]
        assert s["frames"] > 0 and 0.0 <= s["acceptance"] <= 1.0
