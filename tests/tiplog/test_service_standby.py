"""A spare's wait (`tiplog.service.standby`): called up by a line on stdin, ended by end of
file (its supervisor gone) or a stop signal, never joining the bus meanwhile."""

from __future__ import annotations

import io
import logging
import os
import sys
import threading

from tiplog.service import standby

LOG = logging.getLogger("test")


class _Stdin:
    def __init__(self, buffer) -> None:
        self.buffer = buffer


def test_a_line_calls_the_spare_up(monkeypatch):
    monkeypatch.setattr(sys, "stdin", _Stdin(io.BytesIO(b"up\n")))
    assert standby(threading.Event(), LOG) is True


def test_end_of_file_ends_it(monkeypatch):
    monkeypatch.setattr(sys, "stdin", _Stdin(io.BytesIO(b"")))
    assert standby(threading.Event(), LOG) is False


def test_a_stop_ends_it_while_nothing_comes(monkeypatch):
    r, w = os.pipe()
    f = os.fdopen(r, "rb")
    monkeypatch.setattr(sys, "stdin", _Stdin(f))
    stop = threading.Event()
    threading.Timer(0.05, stop.set).start()
    try:
        assert standby(stop, LOG) is False
    finally:
        os.close(w)  # the reader thread sees end of file and lets go of the file
        monkeypatch.undo()
