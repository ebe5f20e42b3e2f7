"""`tiplog sim generate` as a user meets it: a seed, duration or scenario override that
cannot be simulated is one line naming it, exit 2, before any work; the shortest duration it
accepts does simulate."""

from __future__ import annotations

import pytest

from tiplog.cli import main
from tiplog.mcap_io import read_messages


def _argv(tmp_path, *extra):
    return ["sim", "generate", "--scenario", "sweeps", "--quiet", "--out", str(tmp_path / "s.mcap"), *extra]


@pytest.mark.parametrize(
    ("extra", "needles"),
    [
        (["--duration", "nan"], ("--duration", "finite")),
        (["--duration", "inf"], ("--duration", "finite")),
        (["--duration", "0"], ("--duration", "> 0")),
        (["--seed", "-1"], ("--seed", ">= 0")),
    ],
)
def test_option_values_are_refused_while_parsing(tmp_path, capsys, extra, needles):
    with pytest.raises(SystemExit) as e:
        main(_argv(tmp_path, *extra))
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1, err
    for n in needles:
        assert n in err[0], err[0]
    assert not (tmp_path / "s.mcap").exists()


@pytest.mark.parametrize(
    ("extra", "needles"),
    [
        (["--duration", "0.001"], ("--duration", "0.001 s", "tof", "100 Hz", "at least 0.013 s")),
        (["--duration", "0.3", "--set", "tof.rate_hz=2"], ("--duration", "at least 0.503 s")),
        (["--duration", "1", "--set", "protocol=bogus"], ("protocol", "unknown protocol", "'bogus'")),
        (["--duration", "1", "--set", "tof.noise_factor_range=[2,1]"], ("tof.noise_factor_range", "min <= max")),
    ],
)
def test_what_cannot_be_simulated_is_one_line(tmp_path, capsys, extra, needles):
    assert main(_argv(tmp_path, *extra)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    for n in needles:
        assert n in err[0], err[0]
    assert not (tmp_path / "s.mcap").exists()


def test_the_shortest_duration_simulates(tmp_path, capsys):
    assert main(_argv(tmp_path, "--duration", "0.013", "--seed", "4")) == 0
    topics = {r.topic for r in read_messages(tmp_path / "s.mcap")}
    assert {"device/gyro", "device/accel", "device/tof", "device/mag"} <= topics
