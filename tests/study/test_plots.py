"""`tiplog evaluate --plots DIR` into a folder that already holds plots: nothing there is
replaced without --force (refused before any work, naming the file), and every PNG is written
under a temporary name and renamed when complete."""

from __future__ import annotations

import argparse

import pytest

from study.cli import _planned_plots
from tests.services.fusion.sessions import sweeps_estimate_fixture, sweeps_session_fixture  # noqa: F401 (fixtures session, estimate)
from tiplog.cli import main as tiplog_main
from tiplog.mcap_io import McapWriter
from tiplog.plots import pyplot, save

PNG = b"\x89PNG\r\n\x1a\n"


def test_existing_plots_are_kept_without_force_and_replaced_with_it(tmp_path, session, estimate, capsys):
    plots = tmp_path / "plots"
    args = ["evaluate", str(session), "--estimate", str(estimate), "--json", str(tmp_path / "a.json")]
    assert tiplog_main([*args, "--plots", str(plots)]) == 0
    made = sorted(p.name for p in plots.iterdir())
    assert made and all(n.endswith(".png") for n in made)
    first = plots / made[0]
    first.write_bytes(b"my annotated figure")
    (plots / "notes.txt").write_text("mine")
    capsys.readouterr()
    args = ["evaluate", str(session), "--estimate", str(estimate), "--json", str(tmp_path / "b.json")]
    assert tiplog_main([*args, "--plots", str(plots)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"tiplog evaluate: {first}: file exists, use --force to overwrite it"]
    assert first.read_bytes() == b"my annotated figure"
    assert not (tmp_path / "b.json").exists()  # refused before any work
    assert tiplog_main([*args, "--plots", str(plots), "--force"]) == 0
    assert first.read_bytes().startswith(PNG)
    assert (plots / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in plots.iterdir()) == sorted([*made, "notes.txt"])  # no temporary file left


def test_plot_names_are_known_before_the_work(tmp_path, session):
    ns = argparse.Namespace(estimate="est.mcap", ablations=True)
    names = _planned_plots(session, "sweeps", ns)
    assert names[-1] == "ablations.png" and len(names) >= 2 and all(n.endswith(".png") for n in names)
    static = tmp_path / "t.mcap"
    with McapWriter(static) as w:
        w.add_metadata("session", {"protocol": "translation"})
        w.add_metadata("trials", {"json": '[{"kind": "translation"}, {"kind": "translation"}]'})
    assert _planned_plots(static, "translation", ns) == ["translation_boxplots.png"]


def test_a_plot_is_written_whole_or_not_at_all(tmp_path, monkeypatch):
    target = tmp_path / "block.png"
    target.write_bytes(PNG + b"the previous plot")
    plt = pyplot()
    fig = plt.figure()

    def dies_half_way(path, **kw):
        with open(path, "wb") as f:
            f.write(PNG + b"half")
        raise KeyboardInterrupt

    monkeypatch.setattr(fig, "savefig", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        save(fig, target, force=True)
    assert target.read_bytes() == PNG + b"the previous plot"
    assert [p.name for p in tmp_path.iterdir()] == ["block.png"]
    fig = plt.figure()
    with pytest.raises(Exception, match="file exists"):
        save(fig, target, force=False)
    assert target.read_bytes() == PNG + b"the previous plot"
