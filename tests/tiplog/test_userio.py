"""`tiplog.userio`: an output never replaces one of the command's inputs (by any spelling or
link) nor a device, pipe or socket, `--force` or not; an MCAP file whose end is damaged is
refused with where and how to repair it."""

from __future__ import annotations

import os
import socket
import stat

import pytest

from tiplog.mcap_io import McapWriter, read_summary
from tiplog.mcap_salvage import FOOTER, MAGIC
from tiplog.userio import (
    UserError,
    atomic_output,
    damage_note,
    forget_inputs,
    input_file,
    input_mcap,
    output_file,
    register_input,
)
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


@pytest.mark.parametrize("damage", ["appended", "last4cut", "summaryflip"])
def test_mcap_with_a_damaged_end_is_refused_with_how_to_repair_it(tmp_path, damage):
    good = _session(tmp_path / "good.mcap")
    data = bytearray(good.read_bytes())
    if damage == "appended":
        data += b"GARBAGE " * 100
    elif damage == "last4cut":
        data = data[:-4]
    else:
        start = FOOTER.unpack(data[-len(MAGIC) - FOOTER.size : -len(MAGIC)])[2]
        data[start + 20] ^= 0xFF
    bad = tmp_path / f"{damage}.mcap"
    bad.write_bytes(bytes(data))
    assert input_mcap(good) == good
    with pytest.raises(UserError) as e:
        input_mcap(bad)
    msg = str(e.value)
    assert msg.startswith(f"{bad}: ") and f"tiplog record recover {bad}" in msg and "\n" not in msg
    assert ("fails its CRC" in msg) == (damage == "summaryflip")
    assert input_mcap(bad, allow_truncated=True) == bad  # record recover, info and replay read it as a stream


def test_damage_note_says_where_a_chunk_fails_its_crc(tmp_path):
    good = _session(tmp_path / "good.mcap")
    assert damage_note(good) is None  # nothing wrong: a reader failure is not the file's
    data = bytearray(good.read_bytes())
    chunks = read_summary(good).chunk_indexes
    assert len(chunks) > 2
    c = chunks[len(chunks) // 2]
    mid = c.chunk_start_offset + c.chunk_length // 2  # inside a chunk's compressed data
    data[mid : mid + 64] = bytes(b ^ 0xFF for b in data[mid : mid + 64])
    bad = tmp_path / "flip.mcap"
    bad.write_bytes(bytes(data))
    note = damage_note(bad)
    assert note is not None and note.startswith(f"{bad}: damaged at byte ")
    at = int(note.split("damaged at byte ")[1].split()[0])
    assert at == c.chunk_start_offset and f"of {len(data)}" in note and f"tiplog record recover {bad}" in note
