"""Every `tiplog` subcommand that takes a file, given the files a user really has lying around
(a path that does not exist, a folder, an empty file, a text file, an MCAP cut short, a file it
cannot read): exit status 2, one line on stderr naming the file, no traceback, and no file
changed. Subcommands and their file options are discovered from the parsers, so a subcommand
that lands later is covered without editing this test."""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tiplog.cli import build_parser

# Option or positional names that take a file (or, for outputs, name one to write).
INPUT_DESTS = {"recording", "file", "input", "calibration", "config", "scenario", "model", "checkpoint", "weights"}
OUTPUT_DESTS = {"out", "output"}
FILE_METAVARS = {"FILE", "MCAP", "RECORDING", "PATH", "CONFIG", "YAML"}
KINDS = ["missing", "folder", "empty", "text", "truncated", "unreadable"]
CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH = 1, 2


def drop_file_read_override() -> None:
    """As root, give up the capabilities that let root read any file (effective and permitted,
    which access() uses): a mode-0 file is then unreadable, while root still owns and reads its
    own files (the interpreter's, the test's)."""
    import ctypes

    class Header(ctypes.Structure):
        _fields_ = [("version", ctypes.c_uint32), ("pid", ctypes.c_int)]

    class Data(ctypes.Structure):
        _fields_ = [("effective", ctypes.c_uint32), ("permitted", ctypes.c_uint32), ("inheritable", ctypes.c_uint32)]

    libc = ctypes.CDLL(None, use_errno=True)
    hdr, data = Header(0x20080522, 0), (Data * 2)()  # _LINUX_CAPABILITY_VERSION_3
    if libc.capget(ctypes.byref(hdr), data) != 0:
        raise OSError(ctypes.get_errno(), "capget")
    mask = ~((1 << CAP_DAC_OVERRIDE) | (1 << CAP_DAC_READ_SEARCH)) & 0xFFFFFFFF
    data[0].effective &= mask
    data[0].permitted &= mask
    if libc.capset(ctypes.byref(hdr), data) != 0:
        raise OSError(ctypes.get_errno(), "capset")


def leaf_parsers(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()):
    """(argv prefix, parser) of every runnable subcommand."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield prefix, parser
        return
    seen: set[int] = set()
    for name, sub in subs[0].choices.items():
        if id(sub) not in seen:
            seen.add(id(sub))
            yield from leaf_parsers(sub, prefix + (name,))


def file_actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    out = []
    for a in parser._actions:
        if isinstance(a, (argparse._HelpAction, argparse._StoreTrueAction, argparse._StoreFalseAction)):
            continue
        if a.dest in INPUT_DESTS | OUTPUT_DESTS or (isinstance(a.metavar, str) and a.metavar.upper() in FILE_METAVARS):
            out.append(a)
    return out


def cases():
    for prefix, parser in leaf_parsers(build_parser("all")):
        for action in file_actions(parser):
            flag = action.option_strings[-1] if action.option_strings else action.dest
            for kind in KINDS:
                yield pytest.param(prefix, action.dest, kind, id=f"{' '.join(prefix)}:{flag}:{kind}")


def find_leaf(prefix: tuple[str, ...]) -> argparse.ArgumentParser:
    return dict(leaf_parsers(build_parser("all")))[prefix]


@pytest.fixture(scope="module")
def workdir():
    """A folder with a valid short session and a valid configuration file."""
    from services.bench.scenario import load_scenario
    from services.bench.session import generate

    d = Path(tempfile.mkdtemp(prefix="tiplog-cli-files-"))
    generate(load_scenario("static"), d / "valid.mcap", seed=1, duration_s=1.0)
    (d / "valid.yaml").write_text("bus:\n  mode: peer\n")
    yield d
    shutil.rmtree(d, ignore_errors=True)


def make_bad(d: Path, kind: str) -> Path:
    p = d / f"bad-{kind}.mcap"
    if kind == "missing":
        return d / "no-such-folder" / "missing.mcap"
    if kind == "folder":
        p = d / "a-folder.mcap"
        p.mkdir(exist_ok=True)
        return p
    if kind == "empty":
        p.write_bytes(b"")
    elif kind == "text":
        p.write_text("these are my notes, not a recording\n")
    elif kind == "truncated":
        data = (d / "valid.mcap").read_bytes()
        p.write_bytes(data[: len(data) * 2 // 3])
    elif kind == "unreadable":
        p.write_bytes((d / "valid.mcap").read_bytes())
        p.chmod(0)
    return p


# Optional arguments that keep a run short when everything else is valid (replay as fast as
# possible, without waiting for a subscriber).
QUICK = {"max": [], "wait": ["0"]}
# A truncated MCAP is what `record recover` exists for: it rebuilds it (exit 0).
ACCEPTS_TRUNCATED = {(("record", "recover"), "file")}


def baseline(parser: argparse.ArgumentParser, d: Path, dest: str, value: str) -> list[str]:
    """Arguments with `value` for `dest` and valid values for every other required one."""
    positionals: list[str] = []
    options: list[str] = []
    for a in parser._actions:
        if isinstance(a, argparse._HelpAction):
            continue
        positional = not a.option_strings
        if a.dest == dest:
            v = value
        elif a.dest in QUICK and not positional:
            options += [a.option_strings[-1], *QUICK[a.dest]]
            continue
        elif (positional and a.nargs in ("?", "*")) or (not positional and not a.required):
            continue
        elif a.dest in OUTPUT_DESTS:
            v = str(d / "fresh-output.mcap")
        elif a.dest == "scenario":
            v = "static"
        elif a.dest == "config":
            v = str(d / "valid.yaml")
        elif a.dest in INPUT_DESTS or (isinstance(a.metavar, str) and a.metavar.upper() in FILE_METAVARS):
            v = str(d / "valid.mcap")
        elif a.choices:
            v = str(next(iter(a.choices)))
        else:
            v = "x"
        if positional:
            positionals.append(v)
        else:
            options += [a.option_strings[-1], v]
    return positionals + options


def snapshot(d: Path) -> dict[str, tuple]:
    """Relative path -> (size, sha1) of everything under `d` (root reads mode-0 files)."""
    out = {}
    for p in sorted(d.rglob("*")):
        digest = hashlib.sha1(p.read_bytes()).hexdigest() if p.is_file() else "folder"
        out[str(p.relative_to(d))] = (p.lstat().st_size if p.is_file() else 0, digest)
    return out


def run_forked(
    argv: list[str], d: Path, as_root_without_override: bool, timeout_s: float = 60.0
) -> tuple[int, str, str]:
    """`tiplog.cli.main(argv)` in a forked child (its signal handlers and logging stay there;
    a hang is killed): (exit status, stdout, stderr)."""
    out_fd, out_path = tempfile.mkstemp()
    err_fd, err_path = tempfile.mkstemp()
    pid = os.fork()
    if pid == 0:  # child
        rc = 99
        try:
            os.dup2(out_fd, 1)
            os.dup2(err_fd, 2)
            sys.stdout = os.fdopen(1, "w", buffering=1)
            sys.stderr = os.fdopen(2, "w", buffering=1)
            if as_root_without_override:
                drop_file_read_override()
            os.chdir(d)
            from tiplog.cli import main

            rc = main(argv)
        except SystemExit as e:
            rc = e.code if isinstance(e.code, int) else 2
        except BaseException:
            import traceback

            traceback.print_exc()
            rc = 98
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(rc)
    os.close(out_fd)
    os.close(err_fd)
    deadline = time.monotonic() + timeout_s
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            pytest.fail(f"tiplog {' '.join(argv)} still running after {timeout_s} s")
        time.sleep(0.02)
    out, err = Path(out_path).read_text(), Path(err_path).read_text()
    os.unlink(out_path)
    os.unlink(err_path)
    return os.waitstatus_to_exitcode(status), out, err


@pytest.mark.slow  # ~200 runs of the command line: 1-2 minutes on a 2-core machine
@pytest.mark.parametrize("prefix,dest,kind", list(cases()))
def test_bad_file_is_one_line_exit_2_and_nothing_changes(prefix, dest, kind, workdir):
    if kind == "truncated" and (prefix, dest) in ACCEPTS_TRUNCATED:
        pytest.skip(f"tiplog {' '.join(prefix)} exists to read files cut short")
    parser = find_leaf(prefix)
    bad = make_bad(workdir, kind)
    argv = [*prefix, *baseline(parser, workdir, dest, str(bad))]
    before = snapshot(workdir)
    rc, out, err = run_forked(argv, workdir, kind == "unreadable" and os.geteuid() == 0)
    after = snapshot(workdir)
    if "not available in this build yet" in err or "not available yet" in err:
        pytest.skip(f"tiplog {' '.join(prefix)}: not available in this build yet")
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, f"tiplog {' '.join(argv)}: exit {rc}\nstderr:\n{err}"
    assert "Traceback" not in err, err
    assert len(lines) == 1, f"expected one line on stderr, got:\n{err}"
    if dest not in OUTPUT_DESTS:  # an output may be checked after the inputs, which are valid here
        assert bad.name in lines[0], f"the line does not name {bad.name}: {lines[0]}"
    assert after == before, "a file changed or appeared"


def test_discovery_finds_the_file_options_of_todays_commands():
    found = {(" ".join(p), d) for p, d, _ in (c.values for c in cases())}
    for expected in [
        ("info", "recording"),
        ("replay", "recording"),
        ("replay", "config"),
        ("sim generate", "out"),
        ("sim generate", "scenario"),
        ("sim report", "recording"),
        ("record recover", "file"),
        ("record recover", "out"),
        ("record run", "config"),
        ("up", "config"),
        ("up", "calibration"),
    ]:
        assert expected in found, expected


@pytest.mark.slow
def test_ctrl_c_during_sim_generate_leaves_no_file(tmp_path):
    out = tmp_path / "session.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "tiplog.cli", "sim", "generate", "--scenario", "translation", "--out", str(out)],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # as in a terminal: a suite started in the background (nohup, CI runners) ignores SIGINT,
        # and the child would inherit that and run to the end
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        # the temporary file appears once the work has begun (progress is silent off a terminal)
        deadline = time.monotonic() + 120
        while not list(tmp_path.iterdir()) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None, "sim generate ended before writing its temporary file"
        partial = list(tmp_path.iterdir())
        assert len(partial) == 1 and partial[0].name.endswith(".partial"), partial
        proc.send_signal(signal.SIGINT)
        rest = proc.stderr.read()
        rc = proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 130
    assert "Traceback" not in rest, rest
    assert list(tmp_path.iterdir()) == []
