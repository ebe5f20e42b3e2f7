"""`tiplog.userio`: an output never replaces one of the command's inputs (by any spelling or
link) nor a device, pipe or socket, `--force` or not."""

from __future__ import annotations

import os
import socket
import stat

import pytest

from tiplog.mcap_io import McapWriter
from tiplog.userio import UserError, atomic_output, forget_inputs, input_file, input_mcap, output_file, register_input
from tiplog.v1 import device_pb2


@pytest.fixture(autouse=True)
def _fresh_inputs():
    forget_inputs()
    yield
    forget_inputs()


def _session(path, n=400):
    with McapWriter(path, chunk_size=4096) as w:  # several chunks
        for k in range(n):
            m = device_pb2.Gyro()
            m.header.seq = k
            m.rate_radps.z = 0.001 * k
            w.write("device/gyro", m, log_time_ns=1000 * k, sequence=k)
        w.add_metadata("session", {"scenario": "static"})
    return path


def test_output_that_is_an_input_is_refused_by_any_spelling_even_with_force(tmp_path, monkeypatch):
    src = tmp_path / "in.csv"
    src.write_text("t_s\n0\n")
    before = src.read_bytes()
    input_file(src, "CSV file")
    (tmp_path / "sub").mkdir()
    (tmp_path / "link.csv").symlink_to(src)
    os.link(src, tmp_path / "hard.csv")
    monkeypatch.chdir(tmp_path / "sub")
    for spelling in (src, "../in.csv", f"{tmp_path}/sub/../././in.csv", tmp_path / "link.csv", tmp_path / "hard.csv"):
        with pytest.raises(UserError, match="is also an input of this command .*the CSV file.*choose another output"):
            output_file(spelling, force=True)
        with pytest.raises(UserError, match="is also an input"), atomic_output(spelling, force=True) as tmp:
            tmp.write_text("replaced")
    assert src.read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]
    other = tmp_path / "other.csv"
    other.write_text("x")
    assert output_file(other, force=True) == other  # an existing non-input file: --force is enough


def test_inputs_are_the_commands_own(tmp_path):
    src = tmp_path / "in.mcap"
    _session(src)
    input_mcap(src)
    with pytest.raises(UserError, match="MCAP file"):
        output_file(src, force=True)
    forget_inputs()  # the next command (tiplog.cli.main) starts afresh
    assert output_file(src, force=True) == src


def test_an_input_written_later_is_refused_when_the_output_is_committed(tmp_path):
    """An input read after the early check (an image in a folder) still cannot be replaced:
    atomic_output checks again before the rename."""
    img = tmp_path / "v00.png"
    img.write_bytes(b"\x89PNG data")
    with pytest.raises(UserError, match="chessboard image"):
        with atomic_output(img, force=True) as tmp:
            register_input(img, "chessboard image")
            tmp.write_text("calibration: {}\n")
    assert img.read_bytes() == b"\x89PNG data"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v00.png"]


def test_a_device_pipe_or_socket_is_never_replaced(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    sock_path = tmp_path / "s.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(str(sock_path))
    try:
        for p in (fifo, sock_path):
            for force in (False, True):
                with pytest.raises(UserError, match="not a regular file"):
                    output_file(p, force)
                with pytest.raises(UserError, match="not a regular file"), atomic_output(p, force) as tmp:
                    tmp.write_text("x")
        assert stat.S_ISFIFO(fifo.lstat().st_mode) and stat.S_ISSOCK(sock_path.lstat().st_mode)
    finally:
        sock.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo", "s.sock"]
