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
    assert r["frames_timed"] == 4
    for stage in ("labeler", "network", "total"):
        assert 0 < r["per_frame"][f"{stage}_ms"]["p50"] <= r["per_frame"][f"{stage}_ms"]["p95"]
        assert r["per_frame"][f"{stage}_cpu_ms"]["p50"] > 0
    assert len(r["per_frame_load"]) == 2
    frames = sum(1 for _ in read_messages(recording, ["camera/image"]))
    assert [v["workers"] for v in r["vision_run"]] == [1, 2]
    for v in r["vision_run"]:
        assert v["frames"] == frames and v["fps"] > 0 and v["load_before"] >= 0


def test_accuracy_benchmark_runs(tmp_path):
    from benchmarks import vision_accuracy

    out = tmp_path / "acc.json"
    assert vision_accuracy.main(["--scenario", "demo", "--seeds", "1001", "--duration", "0.5", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    for tier in ("pixel", "model"):
        s = r["pooled"][tier]
        assert s["frames"] > 0 and 0.0 <= s["acceptance"] <= 1.0
    bins = r["by_speed"]
    assert sum(b["pixel"]["frames"] for b in bins) == r["pooled"]["pixel"]["frames"]
    assert sum(b["model"]["frames"] for b in bins) == r["pooled"]["model"]["frames"]


def test_accuracy_benchmark_refuses_a_bad_override(capsys):
    from benchmarks import vision_accuracy

    assert vision_accuracy.main(["--seeds", "1", "--set", "render.exposure_ms=-3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "render.exposure_ms" in err[0]
