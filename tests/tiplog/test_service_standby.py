"""A spare's wait (`tiplog.service.standby`): called up by a line on stdin, ended by end of
file (its supervisor gone) or a stop signal, never joining the bus meanwhile."""

from __future__ import annotations

import logging
import os
import sys
import threading

from tiplog.service import standby

LOG = logging.getLogger("test")


def _stdin(monkeypatch, written: bytes | None):
    """A pipe as stdin with `written` in it, closed for writing unless None."""
    r, w = os.pipe()
    if written is not None:
        os.write(w, written)
        os.close(w)
    monkeypatch.setattr(sys, "stdin", os.fdopen(r, "rb"))
    return w


def test_a_line_calls_the_spare_up(monkeypatch):
    _stdin(monkeypatch, b"up\n")
    assert standby(threading.Event(), LOG) is True


def test_end_of_file_ends_it(monkeypatch):
    _stdin(monkeypatch, b"")
    assert standby(threading.Event(), LOG) is False


def test_a_stop_ends_it_while_nothing_comes(monkeypatch):
    w = _stdin(monkeypatch, None)
    stop = threading.Event()
    threading.Timer(0.05, stop.set).start()
    try:
        assert standby(stop, LOG) is False
    finally:
        os.close(w)  # the reader thread sees end of file and lets go of the file
        monkeypatch.undo()
