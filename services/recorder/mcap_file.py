"""One recording file: an McapWriter over a stream that reports every failed write, and a
salvage path that leaves the file valid when the disk fills or the directory goes away.

The McapWriter is flushed (chunk closed, bytes handed to the OS) every `flush_period_s`.
Every writer call that returns leaves the stream at a record boundary (a whole chunk with its
message indexes, or nothing), a point where the file is a valid MCAP data section. A write
that fails (ENOSPC, EIO, an unplugged disk) leaves a partial record after the last such
point: `salvage()` truncates the file back to it and ends it with DataEnd + Footer + magic,
so every reader opens it (without summary; `tiplog record recover` rebuilds the indexes).
"""

from __future__ import annotations

import errno
import logging
import os
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from mcap.data_stream import RecordBuilder
from mcap.records import DataEnd, Footer

from tiplog.mcap_io import McapWriter

log = logging.getLogger(__name__)
MAGIC = b"\x89MCAP0\r\n"

# Opens a file for writing in binary mode; the seam tests use to inject a full disk.
Opener = Callable[[Path], IO[bytes]]


def open_file(path: Path) -> IO[bytes]:
    return open(path, "wb", buffering=0)  # noqa: SIM115  (closed by RecordingFile)


class _CheckedStream:
    """Write-all wrapper: a short write becomes an OSError instead of a silent gap."""

    def __init__(self, raw: IO[bytes]):
        self.raw = raw
        self.position = 0

    def write(self, data: bytes | memoryview) -> int:
        mv = memoryview(data)
        total = len(mv)
        while len(mv):
            n = self.raw.write(mv)
            if not n:
                raise OSError(errno.ENOSPC, "short write (disk full?)")
            mv = mv[n:]
        self.position += total
        return total

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        self.raw.flush()

    def fsync(self) -> None:
        os.fsync(self.raw.fileno())


class RecordingFile:
    """An open MCAP file of the recorder; all calls from the writer thread only."""

    def __init__(self, path: Path, *, compression: str, chunk_size: int, opener: Opener = open_file):
        self.path = path
        self._raw = opener(path)
        _fsync_dir(path.parent)  # the new name itself survives a power cut
        self._stream = _CheckedStream(self._raw)
        try:
            self.writer = McapWriter(self._stream, compression=compression, chunk_size=chunk_size)  # type: ignore[arg-type]
        except BaseException:  # not even the header fits: leave no open descriptor behind
            self._raw.close()
            raise
        self.good_offset = 0  # end of the last complete record written (a valid prefix)
        # Earlier boundaries too: on a full disk the ~30-byte end of file may not fit after the
        # last one, and cutting back one more record frees the room for it.
        self._boundaries: deque[int] = deque(maxlen=16)
        self.written_by_topic: dict[str, int] = {}
        self.quarantined_bytes = 0  # payload bytes kept on `_rejected/...` channels
        self.first_log_ns: int | None = None
        self.last_log_ns: int | None = None
        self.closed = False

    def _mark(self) -> None:
        pos = self._stream.position
        if pos != self.good_offset:
            self._boundaries.append(self.good_offset)
        self.good_offset = pos

    @property
    def bytes_written(self) -> int:
        return self._stream.position

    def write(self, topic: str, type_name: str, payload: bytes, log_ns: int, publish_ns: int, sequence: int) -> None:
        self.writer.write_raw(topic, type_name, payload, log_ns, publish_ns, sequence)
        # A call that returns leaves the stream at a record boundary (a whole chunk and its
        # message indexes, or nothing): the file is valid up to here.
        self._mark()
        self.written_by_topic[topic] = self.written_by_topic.get(topic, 0) + 1
        if self.first_log_ns is None:
            self.first_log_ns = log_ns
        self.last_log_ns = log_ns

    def add_metadata(self, name: str, data: dict[str, Any]) -> None:
        self.writer.add_metadata(name, data)
        self._mark()

    def add_attachment(self, name: str, data: bytes, media_type: str, log_ns: int) -> None:
        self.writer.add_attachment(name, data, media_type, log_ns)
        self._mark()

    def flush(self) -> None:
        self.writer.flush()
        self._mark()

    def fsync(self) -> None:
        self._stream.fsync()

    def close(self) -> None:
        """Finish the file (summary, indexes, statistics) and close it."""
        if self.closed:
            return
        self.writer.close()
        self._stream.flush()
        self.closed = True
        try:
            self._stream.fsync()
        except (OSError, ValueError, AttributeError):  # a stream without a descriptor (tests)
            pass
        self._raw.close()

    def salvage(self) -> bool:
        """After a failed write: cut back to the last complete flush and end the file there.
        True when the file ends validly (readable by every reader, without summary)."""
        if self.closed:
            return True
        self.closed = True
        ok = False
        last_error: OSError | None = None
        rb = RecordBuilder()
        DataEnd(0).write(rb)
        Footer(0, 0, 0).write(rb)
        tail = rb.end() + MAGIC
        candidates = [self.good_offset, *reversed(self._boundaries)]
        for offset in candidates:
            try:
                self._raw.truncate(offset)
                self._raw.seek(offset)
                self._stream.position = offset
                self._stream.write(tail)
                self._raw.flush()
                ok = True
                if offset != self.good_offset:
                    log.warning(
                        "%s: cut back %d bytes more to make room for its end", self.path, self.good_offset - offset
                    )
                    self.good_offset = offset
                break
            except OSError as e:
                last_error = e
        if not ok:
            log.error(
                "could not end %s after a write failure (%s); `tiplog record recover` reads it", self.path, last_error
            )
        try:
            self._raw.close()
        except OSError as e:
            log.error("closing %s failed: %s", self.path, e)
        return ok


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
