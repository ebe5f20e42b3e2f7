"""Damage where MCAP has no CRC, on a real session: a metadata record whose length or map is
garbled is one line saying where (exit 2, nothing written), never a traceback nor a
calibration read from damaged bytes; a damaged message index (no tiplog reader uses one) leaves
every message read right, with one warning line. Offsets come from mcap's own record reader."""

from __future__ import annotations

import os
import struct
import subprocess
import sys

import pytest
from mcap.reader import make_reader
from mcap.records import Metadata
from mcap.stream_reader import StreamReader

from tests.conftest import ROOT, free_port
from tests.services.fusion.sessions import sweeps_session_fixture  # noqa: F401 (fixture session)
from tiplog import mcap_salvage
from tiplog.mcap_io import read_messages, read_metadata, read_summary
from tiplog.userio import UserError, forget_inputs, input_mcap

CALIBRATION = "calibration_as_calibrated"  # the metadata record `fusion run` takes its constants from


def layout(path) -> list[tuple[int, object]]:
    """(first byte, record) of every record in file order, chunks not broken up."""
    out = []
    with open(path, "rb") as f:
        at = 8  # after the magic
        for rec in StreamReader(f, emit_chunks=True).records:  # reads exactly each record
            out.append((at, rec))
            at = f.tell()
    return out


def metadata_at(path, name: str) -> int:
    return next(at for at, r in layout(path) if isinstance(r, Metadata) and r.name == name)


def damaged(src, dst, kind: str) -> tuple[object, int]:
    """A copy of `src` with one record damaged; (the copy, the damaged record's first byte)."""
    data = bytearray(src.read_bytes())
    if kind.startswith("metadata"):
        at = metadata_at(src, CALIBRATION)
        (name_len,) = struct.unpack_from("<I", data, at + 9)
        if kind == "metadata-length":  # the record's own length: 100 bytes too long
            (n,) = struct.unpack_from("<Q", data, at + 1)
            struct.pack_into("<Q", data, at + 1, n + 100)
        elif kind == "metadata-map":  # the map's byte length: 7 bytes past the record
            (n,) = struct.unpack_from("<I", data, at + 13 + name_len)
            struct.pack_into("<I", data, at + 13 + name_len, n + 7)
        else:  # 16 bytes of the calibration's JSON inverted: not text any more
            mid = at + 13 + name_len + 40
            data[mid : mid + 16] = bytes(b ^ 0xFF for b in data[mid : mid + 16])
    elif kind == "summary":  # one byte of the first chunk index, in the summary after the data
        at = next(at for at, r in layout(src) if type(r).__name__ == "ChunkIndex")
        data[at + 20] ^= 0xFF
    else:  # the second message index after the first chunk: its length, or 64 bytes of entries
        ci = read_summary(src).chunk_indexes[0]
        at = sorted(ci.message_index_offsets.values())[1]
        if kind == "index-length":
            (n,) = struct.unpack_from("<Q", data, at + 1)
            struct.pack_into("<Q", data, at + 1, n + 48)
        else:
            data[at + 15 : at + 79] = bytes(b ^ 0xFF for b in data[at + 15 : at + 79])
    dst.write_bytes(bytes(data))
    return dst, at


def tiplog(*argv) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "tiplog.cli", *map(str, argv)],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=300,
    )


def lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


@pytest.mark.parametrize("kind", ["metadata-length", "metadata-map", "metadata-text"])
def test_a_damaged_metadata_record_is_one_line_naming_it(session, tmp_path, kind):
    with open(session, "rb") as f:  # the intact file reads as mcap's own reader reads it
        assert read_metadata(session) == {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
    bad, at = damaged(session, tmp_path / f"{kind}.mcap", kind)
    where = f"{bad}: damaged at byte {at} (metadata record '{CALIBRATION}'"
    with pytest.raises(UserError, match="its metadata cannot be trusted") as e:
        read_metadata(bad)
    assert str(e.value).startswith(where), e.value
    out = tmp_path / "est.mcap"
    r = tiplog("fusion", "run", bad, "--out", out, "--quiet")
    err = lines(r.stderr)
    assert r.returncode == 2 and len(err) == 1 and err[0].startswith(f"tiplog fusion: {where}"), r.stderr
    assert not out.exists()
    if kind == "metadata-map":  # info shows what it read, then says where (it was a traceback)
        r = tiplog("info", bad)
        err = lines(r.stderr)
        assert r.returncode == 2 and len(err) == 1 and err[0].startswith(f"tiplog info: {where}"), r.stderr
        assert "topic" in r.stdout


def test_a_damaged_message_index_warns_once_and_reads_every_message_right(session, tmp_path):
    bad, at = damaged(session, tmp_path / "index.mcap", "index-entries")
    clean_out, bad_out = tmp_path / "clean.est.mcap", tmp_path / "bad.est.mcap"
    assert tiplog("fusion", "run", session, "--out", clean_out, "--quiet").returncode == 0
    r = tiplog("fusion", "run", bad, "--out", bad_out, "--quiet")
    warnings = [ln for ln in lines(r.stderr) if " INFO " not in ln]  # fusion run's summary line is INFO
    assert r.returncode == 0 and len(warnings) == 1, r.stderr
    assert "WARNING" in warnings[0] and f"{bad}: damaged at byte {at} (the message index of channel" in warnings[0]

    def states(p):
        return [(x.log_time_ns, x.message.SerializeToString()) for x in read_messages(p, ["fusion/state"])]

    assert states(bad_out) == states(clean_out) and len(states(clean_out)) > 100


def test_replay_of_a_file_with_a_damaged_message_index_warns_and_replays_everything(session, tmp_path):
    bad, at = damaged(session, tmp_path / "index.mcap", "index-length")
    r = tiplog("replay", bad, "--max", "--wait", "0", "--mode", "peer", "-l", f"tcp/127.0.0.1:{free_port()}")
    err = lines(r.stderr)
    assert r.returncode == 0 and len(err) == 1, r.stderr
    assert f"{bad}: damaged at byte {at} (the message index of channel" in err[0], err[0]
    n = read_summary(session).statistics.message_count
    assert f"replayed {n} messages" in r.stdout, r.stdout


def test_info_says_when_the_summary_it_read_fails_its_crc(session, tmp_path):
    bad, _ = damaged(session, tmp_path / "summary.mcap", "summary")
    r = tiplog("info", bad)  # it showed what the damaged index gave and exited 0
    err = lines(r.stderr)
    assert r.returncode == 2 and len(err) == 1 and "topic" in r.stdout, r.stderr
    assert err[0] == (
        f"tiplog info: {bad}: its summary (the index after the data) fails its CRC check; "
        f"run `tiplog record recover {bad}` for a repaired file"
    )


def changed_digit(src, dst):
    """A copy of `src` with one digit of its calibration metadata changed: the same length, still
    text, so the record parses and matches its index; only the data section's CRC can tell."""
    data = bytearray(src.read_bytes())
    i = data.index(b"0.", metadata_at(src, CALIBRATION)) + 3
    data[i] = ord("7") if data[i] != ord("7") else ord("3")
    dst.write_bytes(bytes(data))
    return dst


def test_a_changed_digit_in_the_calibration_is_refused_shown_by_info_and_copied_by_recover(session, tmp_path):
    bad = changed_digit(session, tmp_path / "digit.mcap")
    assert read_metadata(bad)[CALIBRATION] != read_metadata(session)[CALIBRATION]  # read as if whole
    assert not mcap_salvage.data_crc_fails(session) and mcap_salvage.data_crc_fails(bad)
    out = tmp_path / "est.mcap"
    r = tiplog("fusion", "run", bad, "--out", out, "--quiet")  # ran on the changed constants, exit 0
    err = lines(r.stderr)
    assert r.returncode == 2 and len(err) == 1 and not out.exists(), r.stderr
    assert err[0].startswith(f"tiplog fusion: {bad}: its data section fails the CRC its writer recorded")
    assert "its metadata cannot be trusted" in err[0]
    r = tiplog("info", bad)
    err = lines(r.stderr)
    assert r.returncode == 2 and len(err) == 1 and "topic" in r.stdout, r.stderr
    assert "fails the CRC its writer recorded" in err[0]
    copy = tmp_path / "copy.mcap"
    r = tiplog("record", "recover", bad, "--out", copy)
    assert r.returncode == 0 and "copied as they were read" in r.stderr, r.stderr
    assert read_metadata(copy)[CALIBRATION] == read_metadata(bad)[CALIBRATION]
    assert tiplog("fusion", "run", copy, "--out", out, "--quiet").returncode == 0  # the user's choice


def test_a_file_whose_writer_recorded_no_data_crc_is_read_as_before(session, tmp_path):
    """A zero data-section CRC means none was recorded (other writers, older files): nothing to check."""
    data = bytearray(changed_digit(session, tmp_path / "digit.mcap").read_bytes())
    footer_at = len(data) - 8 - mcap_salvage.FOOTER.size
    start = mcap_salvage.FOOTER.unpack_from(data, footer_at)[2]
    end_at = start - mcap_salvage.DATA_END.size
    assert data[end_at] == mcap_salvage.DATA_END_OPCODE
    data[end_at + 9 : end_at + 13] = bytes(4)
    old = tmp_path / "no_crc.mcap"
    old.write_bytes(bytes(data))
    assert not mcap_salvage.data_crc_fails(old)
    try:
        assert input_mcap(old) == old
    finally:
        forget_inputs()  # this command's inputs end here
