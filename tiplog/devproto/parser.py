"""Streaming decoder: bytes in, packets out, every fault counted, never raised.

`StreamParser.feed(data)` splits on the 0x00 delimiter, decodes each chunk (COBS, CRC,
layout) and returns the packets in arrival order. A chunk that fails is counted under the
fault kind the host saw (`crc`, `truncated`, `cobs`, `oversize`, `version`, `unknown_type`,
`bad_payload`) and its bytes under `garbage_bytes`; decoding resumes at the next delimiter.
Per stream it checks the 16-bit sequence counter: a forward jump of d counts one `seq_gaps`
event and d `seq_gap_samples`; a device clock that runs backwards counts a `device_resets`
(the device rebooted: counters restart); a counter that goes back without a reboot counts
`seq_reorder`. Each packet gets `seq_ext`, the counter unwrapped on the host.
"""

from __future__ import annotations

import logging
from collections import Counter

from tiplog.devproto.framing import MAX_ENCODED_SIZE, FrameError, decode_chunk
from tiplog.devproto.packets import SEQ_MODULO, STREAM_NAMES, Packet, PacketType, decode_body

log = logging.getLogger(__name__)

FAULT_KINDS = (
    "crc",
    "truncated",
    "cobs",
    "oversize",
    "version",
    "unknown_type",
    "bad_payload",
    "garbage_bytes",
    "seq_gaps",
    "seq_gap_samples",
    "seq_reorder",
    "device_resets",
)
_HALF = SEQ_MODULO // 2


class StreamParser:
    """Incremental decoder of the device byte stream with fault counters."""

    def __init__(self) -> None:
        self.faults: Counter[str] = Counter({k: 0 for k in FAULT_KINDS})
        self.frames_ok = 0
        self.frames_by_stream: Counter[str] = Counter()
        self._buf = b""
        self._last: dict[PacketType, tuple[int, int, int]] = {}  # type -> (seq, seq_ext, device_us)

    def reset(self) -> None:
        """Drop a partial frame (call on reconnect). Sequence state is kept, so samples lost
        while the port was away count as a gap, and `seq_ext` never goes back."""
        if self._buf:
            self._fault("truncated", len(self._buf), "partial frame dropped on reset")
        self._buf = b""

    @property
    def pending_bytes(self) -> int:
        return len(self._buf)

    def _fault(self, kind: str, nbytes: int, message: str) -> None:
        self.faults[kind] += 1
        self.faults["garbage_bytes"] += nbytes
        n = self.faults[kind]
        if n <= 5 or n % 1000 == 0:
            log.debug("frame fault %s (%d so far): %s", kind, n, message)

    def feed(self, data: bytes) -> list[Packet]:
        """Packets completed by `data`, in order."""
        if not data:
            return []
        buf = self._buf + data if self._buf else data
        chunks = buf.split(b"\x00")
        tail = chunks.pop()  # bytes after the last delimiter: a frame still arriving
        if len(tail) > MAX_ENCODED_SIZE:
            # No delimiter for longer than any frame: garbage; keep only the possible start
            # of a frame (a real one always begins right after a 0x00, so none is lost).
            self._fault("oversize", len(tail), f"{len(tail)} bytes without a delimiter")
            tail = b""
        self._buf = tail
        out: list[Packet] = []
        append = out.append
        for chunk in chunks:
            if not chunk:
                continue
            try:
                pkt = decode_body(decode_chunk(chunk))
            except FrameError as e:
                self._fault(e.kind, len(chunk), str(e))
                continue
            self._sequence(pkt)
            append(pkt)
        self.frames_ok += len(out)
        return out

    def _sequence(self, pkt: Packet) -> None:
        last = self._last.get(pkt.type)
        if last is None:
            pkt.seq_ext = pkt.seq
        else:
            seq0, ext0, us0 = last
            if pkt.device_us < us0:
                self.faults["device_resets"] += 1
                log.info("%s: device clock went back %d us: device reset", STREAM_NAMES[pkt.type], us0 - pkt.device_us)
                pkt.seq_ext = ext0 + 1
            else:
                d = (pkt.seq - seq0 - 1) % SEQ_MODULO
                if d == 0:
                    pkt.seq_ext = ext0 + 1
                elif d < _HALF:
                    self.faults["seq_gaps"] += 1
                    self.faults["seq_gap_samples"] += d
                    pkt.seq_ext = ext0 + 1 + d
                else:
                    self.faults["seq_reorder"] += 1
                    pkt.seq_ext = ext0 + 1
        self._last[pkt.type] = (pkt.seq, pkt.seq_ext, pkt.device_us)
        self.frames_by_stream[STREAM_NAMES[pkt.type]] += 1
