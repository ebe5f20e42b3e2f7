from __future__ import annotations

import subprocess
import sys

import pytest

from tiplog.cli import COMMANDS, build_parser, chosen_command, main


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
        main(["--help"])
    out = capsys.readouterr().out
    for c, (_, help_) in COMMANDS.items():
        assert c in out
        assert help_[:40] in " ".join(out.split()), help_


def test_every_subcommand_registers(capsys):
    """The lazy path must not hide a module that no longer imports or registers."""
    with pytest.raises(SystemExit) as e:
        build_parser("all").parse_args(["--help"])
    assert e.value.code == 0
    assert "fusion" in capsys.readouterr().out


_HEAVY = ("numba", "torch", "scipy", "cv2", "services")


def test_top_level_help_imports_no_subcommand_module():
    """`tiplog --help` lists the commands from their names alone: no subcommand's package, no numba
    kernels, no torch. A fresh interpreter, so that this test session's imports do not count."""
    code = (
        "import sys\n"
        "from tiplog.cli import main\n"
        "try:\n"
        "    main(['--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({_HEAVY!r})))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert "fusion" in r.stdout  # the help was printed
    assert r.stdout.strip().splitlines()[-1] == "[]", r.stdout.splitlines()[-1]


def test_a_chosen_subcommand_imports_its_own_module_only():
    code = (
        "import sys\n"
        "from tiplog.cli import main\n"
        "try:\n"
        "    main(['info', '--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "print(sorted(m for m in sys.modules if m.startswith('services.')))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    mods = r.stdout.strip().splitlines()[-1]
    assert "services.recorder.info_cli" in mods
    assert "services.fusion" not in mods and "services.vision" not in mods, mods


@pytest.mark.parametrize(
    ("argv", "command"),
    [
        ([], None),
        (["--help"], None),
        (["fusion", "run", "x.mcap"], "fusion"),
        (["--log-level", "DEBUG", "info", "x.mcap"], "info"),
        (["--log=DEBUG", "sim", "generate"], "sim"),
        (["bogus"], None),
        (["--log-level"], None),
    ],
)
def test_chosen_command(argv, command):
    assert chosen_command(argv) == command


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


def test_python_dash_m_tiplog_is_the_command(tmp_path):
    """`python -m tiplog`, as where the console script is not on PATH: same parser, same exit status."""
    from tests.conftest import ROOT

    ok = subprocess.run(
        [sys.executable, "-m", "tiplog", "--version"], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert ok.returncode == 0 and ok.stdout.startswith("tiplog ")
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "tiplog",
            "fusion",
            "run",
            str(tmp_path / "missing.mcap"),
            "--out",
            str(tmp_path / "o.mcap"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2 and "missing.mcap" in bad.stderr and "Traceback" not in bad.stderr
