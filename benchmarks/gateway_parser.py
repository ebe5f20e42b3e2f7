"""Device-protocol parser throughput on one core: frames per second through
`StreamParser.feed`, against the device's total rate (gyro 200 + accel 240 + ToF 100 +
mag 100 = 640 frames/s), clean and with injected faults."""

from __future__ import annotations

import argparse
import itertools
import random
import time

from tiplog.devproto.emulator import DEFAULT_RATES_HZ
from tiplog.devproto.packets import SEQ_MODULO, encode_packet_frame
from tiplog.devproto.parser import StreamParser
from tiplog.devproto.synthetic import synthetic_packets

DEVICE_RATE_HZ = sum(DEFAULT_RATES_HZ.values())


def make_stream(n: int, fault_prob: float, seed: int) -> tuple[bytes, int]:
    """(wire bytes of n frames with faults, number of intact frames)."""
    rng = random.Random(seed)
    seqs: dict[int, int] = {}
    out = bytearray()
    intact = 0
    for pkt in itertools.islice(synthetic_packets(DEFAULT_RATES_HZ, seed=seed), n):
        pkt.seq = seqs.get(pkt.type, 0)
        seqs[pkt.type] = (pkt.seq + 1) % SEQ_MODULO
        frame = encode_packet_frame(pkt)
        if fault_prob and rng.random() < fault_prob:
            out += rng.randbytes(rng.randint(1, 64))
        if fault_prob and rng.random() < fault_prob:
            buf = bytearray(frame)
            buf[rng.randint(1, len(frame) - 2)] ^= 1 << rng.randrange(8)
            frame = bytes(buf)
        else:
            intact += 1
        out += frame
    return bytes(out), intact


def measure(data: bytes, chunk: int, repeats: int) -> tuple[float, int]:
    """(best frames/s, frames decoded) feeding `data` in `chunk`-byte reads."""
    best = 0.0
    frames = 0
    pieces = [data[i : i + chunk] for i in range(0, len(data), chunk)]
    for _ in range(repeats):
        parser = StreamParser()
        t0 = time.perf_counter()
        for p in pieces:
            parser.feed(p)
        dt = time.perf_counter() - t0
        frames = parser.frames_ok
        best = max(best, frames / dt)
    return best, frames


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("-n", type=int, default=200_000, help="frames per run")
    ap.add_argument("--chunk", type=int, default=4096, help="bytes per read")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--fault-prob", type=float, default=0.02)
    a = ap.parse_args(argv)
    for label, prob in (("clean", 0.0), (f"faults {a.fault_prob:.0%}", a.fault_prob)):
        data, intact = make_stream(a.n, prob, seed=1)
        rate, frames = measure(data, a.chunk, a.repeats)
        if frames != intact:
            print(f"ERROR: decoded {frames} frames, {intact} were intact")
            return 1
        print(
            f"parser, {label:>10}: {rate:>11,.0f} frames/s on one core "
            f"({len(data) / a.n:.1f} B/frame, {a.chunk} B reads) = x{rate / DEVICE_RATE_HZ:,.0f} "
            f"the device's {DEVICE_RATE_HZ:.0f} frames/s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
