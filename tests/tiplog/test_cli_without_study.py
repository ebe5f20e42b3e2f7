"""The OR image ships without the `study` package (.dockerignore): `tiplog evaluate` there says so
in one line and exits 2, and every other command still works."""

from __future__ import annotations

import subprocess
import sys

from tests.conftest import ROOT

# `study` unimportable, as where it is not installed: a finder ahead of all others refuses it
HIDE = """
import sys
class NoStudy:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] == "study":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name.partition(".")[0])
sys.meta_path.insert(0, NoStudy())
from tiplog.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _tiplog(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", HIDE, *args], cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_evaluate_without_study_is_one_line_exit_2():
    r = _tiplog("evaluate", "continuous", "x.mcap", "--out", "y.md")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "study package is not installed" in lines[0], r.stderr
    assert "Traceback" not in r.stderr


def test_other_commands_without_study():
    r = _tiplog("fusion", "run", "--help")
    assert r.returncode == 0 and "--as-live" in r.stdout, r.stderr
