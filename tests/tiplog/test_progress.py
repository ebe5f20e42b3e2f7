"""tiplog.progress: in place on a terminal, nothing but the final line anywhere else."""

from __future__ import annotations

import io

from tiplog.cli import main
from tiplog.progress import Progress, is_terminal


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_file_gets_no_carriage_returns_only_the_final_line():
    log = io.StringIO()
    with Progress(log, min_interval_s=0.0) as p:
        for k in range(50):
            p.update(f"step {k}", force=True)
        p.close("50 steps")
    assert log.getvalue() == "50 steps\n"


def test_a_log_file_gets_nothing_without_a_final_line():
    log = io.StringIO()
    with Progress(log, min_interval_s=0.0) as p:
        p.update("step 1", force=True)
    assert log.getvalue() == ""


def test_a_terminal_line_is_rewritten_in_place_and_ended():
    term = _Terminal()
    with Progress(term, min_interval_s=0.0) as p:
        p.update("a longer line")
        p.update("short")
    out = term.getvalue()
    assert out.count("\r") == 2 and out.endswith("\n")
    assert "\rshort        " in out  # the longer line's tail is blanked


def test_quiet_writes_nothing_even_on_a_terminal():
    term = _Terminal()
    with Progress(term, enabled=False) as p:
        p.update("x", force=True)
        p.close("done")
    assert term.getvalue() == ""


def test_streams_without_a_terminal_answer():
    class Closed(io.StringIO):
        def isatty(self) -> bool:
            raise ValueError("I/O operation on closed file")

    assert not is_terminal(Closed())
    assert not is_terminal(object())  # type: ignore[arg-type]
    assert is_terminal(_Terminal())


def test_sim_generate_into_a_redirected_stderr_writes_no_carriage_return(tmp_path, capsys):
    out = tmp_path / "s.mcap"
    assert main(["sim", "generate", "--scenario", "sweeps", "--duration", "0.013", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert out.is_file()
    assert "\r" not in captured.err and "\r" not in captured.out
    assert "real time" in captured.out
