"""`tiplog metrics` on short bench sessions: results, event-mark segments, and bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from tests.services.fusion.sessions import (  # noqa: F401 (fixtures session, estimate)
    bench_estimate,
    bench_session,
    sweeps_estimate_fixture,
    sweeps_session_fixture,
)
from tiplog.cli import main as tiplog_main
from tiplog.mcap_io import McapWriter, read_messages, read_metadata

# of the true path; the wobbling display stream below adds about twice the path
PATH_TOLERANCE = 0.25


@pytest.fixture(scope="module")
def teleop(tmp_path_factory) -> tuple[Path, Path]:
    # the clean profile: these tests are about what the command reads and writes; on the paper
    # profile the filter's noisier tip lengthens the path well past PATH_TOLERANCE
    session = bench_session(tmp_path_factory, "teleop", seed=11, duration_s=9.0, profile="clean")
    return session, bench_estimate(tmp_path_factory, session)


def _with_marks(src: Path, dst: Path, marks_s: list[float]) -> Path:
    """A copy of src with event marks (as the recorder writes them) at the given log times."""
    with McapWriter(dst) as w:
        for name, rec in read_metadata(src).items():
            w.add_metadata(name, rec)
        for i, t in enumerate(marks_s):
            w.add_metadata(
                f"event_{i + 1:04d}", {"label": f"task{i + 1}", "log_time_ns": str(int(t * 1e9)), "wall_ns": "0"}
            )
        for r in read_messages(src):
            w.write(r.topic, r.message, r.log_time_ns, r.publish_time_ns, r.sequence)
    return dst


def test_metrics_of_a_bench_session_with_truth_and_plots(teleop, tmp_path, capsys):
    session, est = teleop
    out, plots = tmp_path / "m.json", tmp_path / "plots"
    args = ["metrics", str(session), "--estimate", str(est), "--segments", "none", "--draws", "8"]
    assert tiplog_main([*args, "--json", str(out), "--plots", str(plots)]) == 0
    res = json.loads(out.read_text())
    assert res["source"]["estimate_topic"] == "fusion/state" and res["source"]["truth"] == "bench/robot"
    (seg,) = res["segments"]
    m = seg["metrics"]
    assert m["path_length_mm"]["value"] > 1.0
    # the estimate's noise below the 2 Hz low-pass adds to its path: over 9 s teleop sessions
    # (clean, seeds 11-15) 14-23 % of the true path
    assert abs(m["path_length_mm"]["error"]) < PATH_TOLERANCE * m["path_length_mm"]["truth"]
    assert m["path_length_mm"]["low"] <= m["path_length_mm"]["high"]
    assert m["sparc"]["value"] < 0 and m["ldlj"]["value"] < 0
    assert set(res["coverage"]) >= {"path_length_mm", "sparc"}
    assert sorted(p.name for p in plots.iterdir()) == ["01_all_speed.png", "01_all_volume.png", "segments.png"]
    assert "path_length_mm" in capsys.readouterr().out
    # an existing result is kept without --force
    before = out.read_text()
    assert tiplog_main([*args, "--json", str(out)]) == 2
    assert out.read_text() == before


def test_event_marks_cut_the_recording(teleop, tmp_path):
    session, est = teleop
    marked = _with_marks(session, tmp_path / "marked.mcap", [4.5])
    out = tmp_path / "m.json"
    # the estimate was made from the unmarked file: the same messages, so the same recording
    assert tiplog_main(["metrics", str(marked), "--estimate", str(est), "--draws", "0", "--json", str(out)]) == 0
    names = [s["name"] for s in json.loads(out.read_text())["segments"]]
    assert names == ["start", "task1"]


def test_a_recording_without_fusion_state_is_refused(teleop, tmp_path, capsys):
    session, _ = teleop
    out = tmp_path / "m.json"
    assert tiplog_main(["metrics", str(session), "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no fusion state" in err[0] and "tiplog fusion run" in err[0]
    assert not out.exists()


def test_an_estimate_of_another_session_is_refused(teleop, estimate, tmp_path, capsys):
    session, _ = teleop
    out = tmp_path / "m.json"
    assert tiplog_main(["metrics", str(session), "--estimate", str(estimate), "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another recording" in err[0]
    assert not out.exists()


def test_a_segment_too_short_for_the_metrics_is_refused(teleop, tmp_path, capsys):
    session, est = teleop
    marked = _with_marks(session, tmp_path / "marked.mcap", [4.0, 5.0])
    out, plots = tmp_path / "m.json", tmp_path / "plots"
    args = ["metrics", str(marked), "--estimate", str(est), "--json", str(out), "--plots", str(plots)]
    assert tiplog_main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'task1'" in err[0] and "at least 2 s" in err[0]
    assert not out.exists() and not plots.exists()


def test_a_recording_with_fusion_state_uses_its_settled_stream(teleop, tmp_path):
    # a recording that holds the filter's streams as the live system records them: the display
    # stream on fusion/state and the settled one on fusion/state_settled (here both from an offline run)
    session, est = teleop
    live = tmp_path / "live.mcap"
    with McapWriter(live) as w:
        for name, rec in read_metadata(session).items():
            w.add_metadata(name, rec)
        for r in read_messages(session):
            w.write(r.topic, r.message, r.log_time_ns, r.publish_time_ns, r.sequence)
        for r in read_messages(est, ["fusion/state"]):
            w.write("fusion/state_settled", r.message, r.log_time_ns, r.publish_time_ns, r.sequence)
            # a display stream that wobbles 5 mm at 1 Hz must not be the one read
            r.message.tip_m.x += 0.005 * math.sin(2 * math.pi * r.message.header.stamp_ns * 1e-9)
            w.write("fusion/state", r.message, r.log_time_ns, r.publish_time_ns, r.sequence)
    out = tmp_path / "m.json"
    assert tiplog_main(["metrics", str(live), "--segments", "none", "--draws", "0", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["source"]["estimate_topic"] == "fusion/state_settled"
    assert res["source"]["estimate_file"] == "live.mcap"
    path = res["segments"][0]["metrics"]["path_length_mm"]
    assert abs(path["error"]) < PATH_TOLERANCE * path["truth"]
