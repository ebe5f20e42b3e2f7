from __future__ import annotations

import pytest

from tiplog.cli import COMMANDS, build_parser, main


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: tiplog " + command)
    assert len(out.splitlines()) >= 3


def test_top_level_help_lists_all_subcommands(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--help"])
    out = capsys.readouterr().out
    for c in COMMANDS:
        assert c in out


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["calibrate", "intrinsics", "imgs", "--out", "x.yaml", "--every", "0"], ("--every", ">= 1")),
        (["calibrate", "hand-eye", "p.csv", "--out", "x.yaml", "--heldout", "abc"], ("--heldout", "'abc'")),
        (["sim", "generate", "--scenario", "sweeps"], ("required", "--out")),
        (["bogus"], ("invalid choice", "'bogus'")),
    ],
)
def test_a_command_line_mistake_is_one_line_naming_it(argv, needles, capsys):
    """Not argparse's usage block: one line, the option, and where the usage is."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("tiplog") and ": error: " in err[0] and "--help`" in err[0], err[0]
    for n in needles:
        assert n in err[0], err[0]
