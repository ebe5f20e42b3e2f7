"""How every `tiplog` subcommand meets a user's mistake: one line naming the file or option and
what is wrong, exit status 2, no traceback (see `tiplog.cli.main`). Inputs are checked before
any work starts; outputs are never overwritten without `--force` and are written under a
temporary name in the same folder, renamed only when complete, so an interrupted command never
leaves a half-written file under the final name. Every input checked here is remembered for the
command, and an output that is the same file as one of them is refused, `--force` or not: the
command would replace what it reads. An MCAP file whose end is damaged is refused up front, and
a read that a damaged file explains is one line saying where (`damage_note`, through
`tiplog.mcap_io.reading`), with the command that salvages it. A damaged message index, which no
reader here uses, is one warning line, and a file whose data section fails the CRC its writer
recorded is refused when no chunk explains it (`records_note`)."""

from __future__ import annotations

import logging
import numbers
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml
from mcap.reader import make_reader

from tiplog import mcap_check, mcap_salvage

log = logging.getLogger(__name__)

MCAP_MAGIC = b"\x89MCAP0\r\n"


class UserError(Exception):
    """A mistake in what the user gave (a file, an option): printed as one line, exit 2."""


# (path, what) of every input of the running command; `output_file` refuses these.
_inputs: list[tuple[Path, str]] = []
# MCAP files whose records without a CRC this command has checked (`records_note`).
_checked: set[Path] = set()


def register_input(path: str | os.PathLike, what: str = "input file") -> None:
    """Remember `path` as read by this command, so that no output may replace it."""
    _inputs.append((Path(path), what))


def forget_inputs() -> None:
    """A new command starts: none of its files is an input yet (`tiplog.cli.main`)."""
    _inputs.clear()
    _checked.clear()


def _input_behind(p: Path) -> tuple[Path, str] | None:
    """The registered input that `p` is (the same file, by any spelling or link), if any."""
    for q, what in _inputs:
        try:
            if os.path.samefile(p, q):
                return q, what
        except OSError:  # either side gone or unreadable: not the same existing file
            continue
    return None


def yaml_error_at(e: yaml.YAMLError) -> str:
    """' at line L, column C: problem' for a YAML syntax error (1-based, as editors count)."""
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    problem = getattr(e, "problem", None) or e.__class__.__name__
    at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return f"{at}: {problem}"


def yaml_number(v: Any) -> float | None:
    """A number read from YAML as a float, else None (a bool is not a number). PyYAML reads
    `1e-5` and `2e3` (no dot, or no exponent sign) as strings, so a string that is a number
    counts."""
    if isinstance(v, numbers.Real) and not isinstance(v, bool):
        return float(v)
    if isinstance(v, str):
        try:
            return float(v.strip())
        except ValueError:
            return None
    return None


def read_yaml(path: str | os.PathLike, error: type[Exception], not_text: str) -> Any:
    """The parsed YAML document of `path`, or `error` naming the file: unreadable, not text
    (`not_text` says what was expected), or not YAML (with the line and column)."""
    p = Path(path)
    try:
        return yaml.safe_load(p.read_text())
    except OSError as e:
        raise error(f"{p}: cannot read ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise error(f"{p}: {not_text}") from None
    except yaml.YAMLError as e:
        raise error(f"{p}: not valid YAML{yaml_error_at(e)}") from None


def input_file(path: str | os.PathLike, what: str = "input file") -> Path:
    """`path` as a readable, non-empty regular file, or UserError naming what is wrong. The
    file is registered as an input of the command (see `output_file`)."""
    p = Path(path)
    if not p.exists():
        raise UserError(f"{p}: no such {what}")
    if p.is_dir():
        raise UserError(f"{p}: is a folder, expected a {what}")
    if not os.access(p, os.R_OK):
        raise UserError(f"{p}: permission denied (cannot read the {what})")
    if p.stat().st_size == 0:
        raise UserError(f"{p}: empty file")
    register_input(p, what)
    return p


def input_mcap(path: str | os.PathLike, allow_truncated: bool = False, check_records: bool = True) -> Path:
    """`path` as a readable file that starts with the MCAP magic, or UserError. A file cut short
    (no footer: a crash, a full disk) is refused with how far it can be read and the command
    that rebuilds it, unless `allow_truncated` (the caller then reads it with
    `tiplog.mcap_salvage` and says so with `truncation_note`). The records without a CRC of
    their own are checked (`records_note`) unless not `check_records` (a command that shows or
    copies a damaged file as it is)."""
    p = input_file(path, "MCAP file")
    try:
        with open(p, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as e:
        raise UserError(f"{p}: cannot read ({e.strerror or e})") from None
    if head != MCAP_MAGIC:
        raise UserError(f"{p}: not an MCAP file")
    if allow_truncated:
        if check_records:
            _refuse(records_note(p))
        return p
    if not mcap_salvage.ends_in_order(p):
        state, n = mcap_salvage.scan(p)
        if not state.complete:
            raise UserError(truncation_note(p, state, n))
    problem = mcap_salvage.trailer_problem(p)  # cheap: the footer and the summary's CRC
    if problem:
        raise UserError(trailer_note(p, problem))
    if check_records:
        _refuse(records_note(p))
    return p


def _refuse(note: str | None) -> None:
    if note is not None:
        raise UserError(note)


def records_note(p: Path) -> str | None:
    """The records that carry no CRC of their own, checked once per file and command: one
    line saying what is wrong, or None (also for a file whose end is cut off or damaged: its
    indexes cannot be trusted, and `trailer_problem` speaks for it).

    A chunk header or message index that does not match the summary is one warning line: no
    tiplog reader uses them (each chunk is found through the summary and checked by its CRC),
    so what is read stays right; other MCAP tools may misplace messages. Otherwise, when the
    data section fails the CRC its writer recorded (tiplog's writers record one), the damage is
    a chunk's (None: the read says where, as before), a metadata record that no longer parses
    (a line saying where), or a change inside a record with no CRC that keeps its length, such
    as a digit of the calibration (a line: its metadata cannot be trusted)."""
    if p in _checked or not mcap_salvage.ends_in_order(p) or mcap_salvage.trailer_problem(p):
        return None
    try:
        with open(p, "rb") as f:
            summary = make_reader(f).get_summary()
            damaged = mcap_check.message_index_problem(f, summary, p.stat().st_size) if summary else None
    except Exception:  # noqa: BLE001 - a summary that does not parse: the read itself says where
        return None
    if damaged is not None:
        log.warning(
            "%s: %s; its messages are read from their chunks, which pass their CRC checks, "
            "but other MCAP tools may misplace them",
            p,
            damaged,
        )
    elif mcap_salvage.data_crc_fails(p) and damage_note(p) is None:
        return _changed_records_note(p, summary)
    _checked.add(p)
    return None


def _changed_records_note(p: Path, summary: Any) -> str:
    """The line for a file whose data section fails its CRC though every chunk passes its own."""
    if summary is not None:
        try:
            with open(p, "rb") as f:
                for _ in mcap_check.metadata_records(f, summary, p.stat().st_size):
                    pass
        except mcap_check.DamagedRecord as e:
            return f"{p}: {e}; its metadata cannot be trusted"
    return (
        f"{p}: its data section fails the CRC its writer recorded, though every chunk passes its own: "
        "bytes changed in a record that has no CRC of its own (its metadata: the calibration, the trials), "
        f"so its metadata cannot be trusted; `tiplog record recover {p}` copies it as it now is"
    )


def truncation_note(path: Path, state: mcap_salvage.Salvage, messages: int, used: str = "readable") -> str:
    """One line: where the file was cut, how much of it is usable, how to rebuild it."""
    return (
        f"{path}: cut short at byte {state.good_bytes} of {state.source_bytes} "
        f"({messages} messages {used} before it); run `tiplog record recover {path}` for a complete file"
    )


def trailer_note(path: Path, problem: str) -> str:
    """One line: the data is whole but what follows it is not; how to rebuild the file."""
    return f"{path}: {problem}; run `tiplog record recover {path}` for a repaired file"


def damage_note(path: str | os.PathLike) -> str | None:
    """One line for an MCAP file its reader failed on: where it is damaged (the first record
    that is cut off or fails its CRC, or the end of the file) and how to salvage it; None when
    a pass over the file finds no damage (the failure is then not the file's)."""
    p = Path(path)
    try:
        state, n = mcap_salvage.scan(p)
        problem = "" if not state.complete else mcap_salvage.trailer_problem(p)
    except OSError:
        return None
    if not state.complete:
        kind = state.error.split(":", 1)[0]
        if kind == "CRCValidationError":
            what = "a chunk fails its CRC check"
        else:
            what = f"an unreadable record ({kind})" if kind else "the data section ends early"
        return (
            f"{p}: damaged at byte {state.good_bytes} of {state.source_bytes} ({what}; {n} messages before it); "
            f"run `tiplog record recover {p}` to salvage the part before it"
        )
    return trailer_note(p, problem) if problem else None


def output_file(path: str | os.PathLike, force: bool = False) -> Path:
    """`path` as a place a new file may be written: its folder exists and is writable, and it
    does not exist unless `force`; it is never an input of the command nor a device, pipe or
    socket (`--force` or not); otherwise UserError."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise UserError(f"{p}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise UserError(f"{p}: folder {parent} is not writable")
    if p.is_dir():
        raise UserError(f"{p}: is a folder, expected a file name")
    if p.exists():
        same = _input_behind(p)
        if same is not None:
            q, what = same
            named = f"the {what}" if str(q) == str(p) else f"the {what} {q}"
            raise UserError(f"{p}: is also an input of this command ({named}); choose another output")
        if not p.is_file():
            raise UserError(f"{p}: not a regular file (a device, pipe or socket); choose a file name")
        if not force:
            raise UserError(f"{p}: file exists, use --force to overwrite it")
    return p


@contextmanager
def atomic_output(path: str | os.PathLike, force: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success rename it to `path`, on any exception
    (Ctrl-C included) remove it. Checks `output_file` first."""
    final = output_file(path, force)
    fd, tmp = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".partial", dir=final.parent or ".")
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    tmp_path.chmod(0o666 & ~umask)  # mkstemp's 0600 would be a surprise on the final file
    try:
        yield tmp_path
        output_file(final, force)  # again: it may have appeared while we worked
        os.replace(tmp_path, final)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def plots_folder(arg: str | None) -> Path | None:
    """A `--plots FOLDER` option checked before any work: None when not given; refused when it
    names a file, when its parent is not a writable folder, or without matplotlib."""
    if not arg:
        return None
    plots = Path(arg)
    if plots.exists() and not plots.is_dir():
        raise UserError(f"{plots}: exists and is not a folder")
    if not plots.parent.is_dir() or not os.access(plots.parent, os.W_OK):
        raise UserError(f"{plots}: cannot create the folder here")
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise UserError("--plots needs matplotlib (pip install 'tiplog[plots]')") from None
    return plots
