"""How much of the live data rate the recorder sustains with zero drops.

The full live rate ("1x"): gyro 200 Hz, accel 240 Hz, ToF 100 Hz, mag 100 Hz, device status
1 Hz, raw 1280x720 rgb8 camera frames at 15 fps (2.7 MB each, noise: the worst case for
compression) and fusion state at 200 Hz, about 42 MB/s. This process publishes the streams at
a multiple of that rate over a real Zenoh session on loopback; the recorder runs as its own
process (`python -m services.recorder`). A multiple passes when every published message is
written (no drop, no upstream gap) and the writer has caught up within `--max-lag` seconds of
the last put. Multiples are tried in increasing order until one fails or the publisher itself
cannot keep the pace.

    python -m benchmarks.recorder_throughput [--compression lz4 zstd] [--seconds 6]
"""

from __future__ import annotations

import argparse
import heapq
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from foxglove_schemas_protobuf import RawImage_pb2

from tiplog import topics
from tiplog.bus import Bus, BusConfig
from tiplog.v1 import device_pb2, fusion_pb2, recorder_pb2

ROOT = Path(__file__).resolve().parents[1]
RATES_HZ = {
    "device/gyro": 200.0,
    "device/accel": 240.0,
    "device/tof": 100.0,
    "device/mag": 100.0,
    "device/status": 1.0,
    "camera/image": 15.0,
    "fusion/state": 200.0,
}
W, H = 1280, 720
FRAME_BYTES = W * H * 3
A = recorder_pb2.RecorderAction


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Payloads:
    """Serialised messages per topic; frames are distinct slices of one noise buffer."""

    def __init__(self, seed: int = 1):
        self.noise = _noise(FRAME_BYTES * 5, seed)
        self.small = {
            "device/gyro": device_pb2.Gyro(rate_radps={"x": 0.01, "y": -0.02, "z": 0.3}),
            "device/accel": device_pb2.Accel(specific_force_mps2={"x": 0.1, "y": 0.2, "z": 9.81}),
            "device/tof": device_pb2.Tof(
                range_raw_mm=123.4, status=device_pb2.TOF_STATUS_VALID, range_smoothed_mm=123.0
            ),
            "device/mag": device_pb2.Mag(field_ut={"x": 20.0, "y": -5.0, "z": 40.0}),
            "device/status": device_pb2.DeviceStatus(state=device_pb2.DEVICE_STATE_STREAMING, firmware="bench"),
            "fusion/state": fusion_pb2.FusionState(depth_mm=80.0, tilt_deg=12.0, lag_ms=25.0, vision_locked=True),
        }

    def get(self, topic: str, k: int, stamp_ns: int) -> bytes:
        if topic == "camera/image":
            off = (k % 5) * FRAME_BYTES  # a chunk never holds two copies of one frame
            img = RawImage_pb2.RawImage(width=W, height=H, encoding="rgb8", step=W * 3, frame_id="camera")
            img.timestamp.FromNanoseconds(stamp_ns)
            img.data = self.noise[off : off + FRAME_BYTES]
            return img.SerializeToString()
        m = self.small[topic]
        m.header.seq = k
        m.header.stamp_ns = stamp_ns
        return m.SerializeToString()


def _noise(n: int, seed: int) -> bytes:
    import numpy as np

    return np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()


class StatusWatch:
    def __init__(self) -> None:
        self.last: recorder_pb2.RecorderStatus | None = None
        self.cv = threading.Condition()

    def __call__(self, msg: recorder_pb2.RecorderStatus, _info: object) -> None:
        with self.cv:
            self.last = msg
            self.cv.notify_all()

    def wait(self, pred, timeout: float) -> recorder_pb2.RecorderStatus | None:  # type: ignore[no-untyped-def]
        with self.cv:
            self.cv.wait_for(lambda: self.last is not None and pred(self.last), timeout)
            return self.last if self.last is not None and pred(self.last) else None


def run_multiple(
    bus: Bus, watch: StatusWatch, pubs: dict, payloads: Payloads, multiple: float, seconds: float, max_lag_s: float
) -> dict:
    """Publish every stream at `multiple` x its live rate for `seconds`; the recorder's verdict."""
    (raw,) = bus.request(
        topics.RECORDER_COMMAND,
        recorder_pb2.RecorderCommand(action=A.RECORDER_ACTION_START, session=f"x{multiple:g}").SerializeToString(),
        10,
    )
    start = recorder_pb2.RecorderReply.FromString(raw)
    if not start.ok:
        raise RuntimeError(f"recorder did not start: {start.message}")
    sent = dict.fromkeys(RATES_HZ, 0)
    t0 = time.monotonic_ns() + 50_000_000
    end = t0 + int(seconds * 1e9)
    heap = [(t0, topic) for topic in RATES_HZ]
    heapq.heapify(heap)
    worst_late_ns = 0
    while heap:
        due, topic = heapq.heappop(heap)
        if due >= end:
            continue
        now = time.monotonic_ns()
        if due > now:
            time.sleep((due - now) / 1e9)
        else:
            worst_late_ns = max(worst_late_ns, now - due)
        pubs[topic].put_bytes(payloads.get(topic, sent[topic], due))
        sent[topic] += 1
        heapq.heappush(heap, (due + int(1e9 / (RATES_HZ[topic] * multiple)), topic))
    t_last = time.monotonic()
    t_last_ns = time.monotonic_ns()
    total = sum(sent.values())

    def caught_up(s: recorder_pb2.RecorderStatus) -> bool:
        return sum(s.topics[t].written + s.topics[t].dropped for t in RATES_HZ if t in s.topics) >= total

    st = watch.wait(caught_up, timeout=max(30.0, 10 * max_lag_s))
    lag_s = time.monotonic() - t_last
    (raw,) = bus.request(
        topics.RECORDER_COMMAND, recorder_pb2.RecorderCommand(action=A.RECORDER_ACTION_STOP).SerializeToString(), 60
    )
    stop = recorder_pb2.RecorderReply.FromString(raw)
    final = stop.status
    written = {t: final.topics[t].written for t in RATES_HZ if t in final.topics}
    dropped = sum(final.topics[t].dropped for t in RATES_HZ if t in final.topics)
    gaps = sum(final.topics[t].upstream_gaps for t in RATES_HZ if t in final.topics)
    nbytes = Path(final.path).stat().st_size if final.path and Path(final.path).exists() else 0
    if final.path:
        Path(final.path).unlink(missing_ok=True)
    pace = seconds / max(seconds, (t_last_ns - t0) / 1e9)  # below 1: the publisher fell behind
    ok = st is not None and dropped == 0 and gaps == 0 and written == sent and lag_s <= max_lag_s
    return {
        "multiple": multiple,
        "ok": ok,
        "publisher_pace": pace,
        "publisher_worst_late_ms": worst_late_ns / 1e6,
        "messages": total,
        "frames": sent["camera/image"],
        "dropped": dropped,
        "gaps": gaps,
        "missing": sum(sent.values()) - sum(written.values()),
        "drain_lag_s": lag_s,
        "file_mb_per_s": nbytes / 1e6 / seconds,
        "input_mb_per_s": sent["camera/image"] * FRAME_BYTES / 1e6 / seconds,
    }


def bench(compression: str, multiples: list[float], seconds: float, max_lag_s: float, out_dir: Path) -> list[dict]:
    port = _free_port()
    ep, prefix = f"tcp/127.0.0.1:{port}", f"bench{port}/"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.recorder",
            "--listen",
            ep,
            "--prefix",
            prefix,
            "--set",
            "bus.connect=[]",
            "--set",
            "autostart=never",
            "--set",
            f"out_dir={out_dir}",
            "--set",
            "min_free_bytes=0",
            "--set",
            f"compression={compression}",
            "--set",
            "status_period_s=0.1",
            "--set",
            "log_level=WARNING",
            "--set",
            "max_file_duration_s=0",
            "--set",
            "max_file_bytes=0",
        ],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    results = []
    try:
        with Bus(BusConfig(connect=[ep], prefix=prefix)) as bus:
            watch = StatusWatch()
            bus.subscribe("recorder/status", watch)
            if watch.wait(lambda s: True, 30) is None:
                raise RuntimeError("the recorder never published its status")
            pubs = {t: bus.publisher(t) for t in RATES_HZ}
            payloads = Payloads()
            for m in multiples:
                r = run_multiple(bus, watch, pubs, payloads, m, seconds, max_lag_s)
                r["compression"] = compression
                results.append(r)
                print(
                    f"  {compression:<5} x{m:<5g} {'PASS' if r['ok'] else 'FAIL'}  {r['messages']:>7} msgs "
                    f"({r['frames']} frames, {r['input_mb_per_s']:.0f} MB/s of frames)  dropped {r['dropped']}  "
                    f"missing {r['missing']}  drain lag {r['drain_lag_s']:.2f} s  file {r['file_mb_per_s']:.0f} MB/s  "
                    f"publisher pace {r['publisher_pace']:.0%}",
                    flush=True,
                )
                if not r["ok"] or r["publisher_pace"] < 0.95:
                    break
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
    return results


def check_cost_us(payloads: Payloads, repeats: int = 200) -> dict[str, float]:
    """CPU time of the recorder's admission check (services/recorder/admission.py) per message,
    in microseconds, per topic of the live mix; measured in this process, one thread."""
    from services.recorder.admission import Admission

    adm = Admission()
    out = {}
    for topic in RATES_HZ:
        msgs = [payloads.get(topic, k, 1_000_000 + k) for k in range(5)]
        name = topics.TOPICS[topic].DESCRIPTOR.full_name
        t0 = time.thread_time()
        for k in range(repeats):
            if adm.check(topic, name, msgs[k % 5]) is not None:
                raise RuntimeError(f"the admission check rejects the benchmark's {topic}")
        out[topic] = (time.thread_time() - t0) / repeats * 1e6
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--compression", nargs="+", default=["lz4", "zstd"], choices=["lz4", "zstd", "none"])
    ap.add_argument("--multiples", type=float, nargs="+", default=[1, 2, 3, 4, 6, 8, 12, 16])
    ap.add_argument("--seconds", type=float, default=6.0, help="publishing time per multiple")
    ap.add_argument("--max-lag", type=float, default=1.0, help="seconds the writer may trail the last put")
    ap.add_argument("--out-dir", help="where the recordings go (default: a temporary folder, removed)")
    a = ap.parse_args(argv)
    out = Path(a.out_dir) if a.out_dir else Path(tempfile.mkdtemp(prefix="tiplog-bench-"))
    total_hz = sum(RATES_HZ.values())
    print(
        f"live rate 1x = {total_hz:.0f} msg/s, {RATES_HZ['camera/image'] * FRAME_BYTES / 1e6:.1f} MB/s of frames; {os.cpu_count()} CPUs"
    )
    cost = check_cost_us(Payloads())
    per_s = sum(cost[t] * hz for t, hz in RATES_HZ.items())
    print(
        "admission check per message: "
        + ", ".join(f"{t} {us:.1f} us" for t, us in cost.items())
        + f"; {per_s / 1e4:.2f} % of a core at 1x"
    )
    best = {}
    try:
        for comp in a.compression:
            res = bench(comp, sorted(a.multiples), a.seconds, a.max_lag, out)
            passed = [r["multiple"] for r in res if r["ok"]]
            best[comp] = max(passed) if passed else 0.0
            limited = res and res[-1]["ok"] and res[-1]["publisher_pace"] < 0.95
            note = " (publisher limited: the recorder may sustain more)" if limited else ""
            print(f"{comp}: sustained x{best[comp]:g} of the live rate with zero drops{note}", flush=True)
    finally:
        if not a.out_dir:
            shutil.rmtree(out, ignore_errors=True)
    return 0 if all(v >= 1 for v in best.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
