"""The accuracy benchmark's degraded-vision spans: sixteen blackouts per session, inside the
scored blocks, never overlapping (placed per block they merged into block-long blackouts), or
the paper's sixteen shared over the sessions given; the settled states are scored, or with
--as-live the display stream."""

from __future__ import annotations

import pytest

from study.ablation import blackout_spans as _blackout_spans

S = 1_000_000_000


@pytest.mark.parametrize("length_s", [1, 3, 10])
def test_sixteen_separate_blackouts_inside_the_blocks(length_s):
    blocks = [("sweep_pitch", 10 * S, 90 * S), ("sweep_roll", 100 * S, 190 * S), ("sweep_depth", 200 * S, 270 * S)]
    spans = sorted(_blackout_spans(blocks, length_s * S))
    assert len(spans) == 16
    assert all(b - a == length_s * S for a, b in spans)
    assert all(spans[i][1] <= spans[i + 1][0] for i in range(len(spans) - 1))
    assert all(any(a <= s and e <= b for _, a, b in blocks) for s, e in spans)


def test_a_block_too_short_for_its_share_gets_fewer():
    spans = _blackout_spans([("teleop1", 0, 25 * S)], 10 * S)
    assert len(spans) == 2 and spans[0][1] <= spans[1][0]


def test_smoothed_variants_name_the_variant_they_smooth():
    from benchmarks.fusion_accuracy import split_variant

    assert split_variant("smoothed") == ("full", True)
    assert split_variant("smoothed:blackout10") == ("blackout10", True)
    assert split_variant("blackout10") == ("blackout10", False)


def test_an_unknown_variant_is_refused_before_any_session_is_read(tmp_path, capsys):
    from benchmarks.fusion_accuracy import main

    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "absent.mcap"), "--variants", "full,smoothed:blackout7"])
    assert e.value.code == 2
    assert "unknown variant 'smoothed:blackout7'" in capsys.readouterr().err


def test_shared_blackouts_split_the_papers_sixteen_over_the_sessions_given(tmp_path_factory, tmp_path):
    import json

    from benchmarks.fusion_accuracy import main
    from tests.services.fusion.sessions import bench_session

    short = bench_session(tmp_path_factory, "teleop", 11, 9.0)
    long = bench_session(tmp_path_factory, "teleop", 12, 18.0)
    out = tmp_path / "r.json"
    assert main([str(short), str(long), "--variants", "blackout1", "--shared-blackouts", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    counts = [r["blackouts"] for r in rows]
    assert sum(counts) == 16 and counts[0] < counts[1]  # in proportion to the blocks' length
    assert main([str(short), "--variants", "blackout1", "--json", str(out)]) == 0
    assert json.loads(out.read_text())[0]["blackouts"] == 16  # sixteen per session by default


def test_a_wrong_file_gets_one_line_and_exit_2(tmp_path, capsys):
    from benchmarks.fusion_accuracy import main

    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("not a recording")
    assert main([str(not_mcap), "--calibration", str(tmp_path / "absent.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "absent.yaml" in err[0]
    assert main([str(not_mcap)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "notes.mcap" in err[0]


def test_the_settled_states_are_scored_unless_asked_for_the_live_display(tmp_path_factory, tmp_path):
    import json

    from benchmarks.fusion_accuracy import main
    from tests.services.fusion.sessions import bench_session

    session = bench_session(tmp_path_factory, "teleop", 11, 9.0)
    out = tmp_path / "r.json"
    rows = {}
    for flag in ([], ["--as-live"]):
        assert main([str(session), "--variants", "full,smoothed", *flag, "--json", str(out)]) == 0
        rows[bool(flag)] = {r["variant"]: r for r in json.loads(out.read_text())}
    assert [r["output"] for r in rows[False].values()] == ["settled", "smoothed"]
    assert [r["output"] for r in rows[True].values()] == ["display", "smoothed"]
    settled, display = rows[False]["full"]["pooled"], rows[True]["full"]["pooled"]
    assert settled["tip_rmse_mm"] != display["tip_rmse_mm"]
    assert rows[True]["smoothed"]["pooled"] == rows[False]["smoothed"]["pooled"]  # the smoother has no display
