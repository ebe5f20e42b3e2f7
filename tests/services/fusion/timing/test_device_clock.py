"""Device samples timed by the device's clock: a host stall (samples held up, then arriving in
one burst) leaves their times, and so the estimate, as they were; a restarted device clock is
followed; a device without a clock is timed by arrival."""

from __future__ import annotations

import numpy as np

from services.fusion.timing.device_clock import DeviceClock
from tests.services.fusion.sessions import bench_session
from tiplog.cli import main as tiplog_main
from tiplog.mcap_io import McapWriter, read_messages, read_metadata

OFFSET = 7_000_000_000  # host clock - device clock
LATENCY = 6_750_000


def _stream(n: int = 4000, period: int = 5_000_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(device stamps, arrival stamps) of a 200 Hz stream: arrival = device + offset + latency
    + jitter (0.4 ms SD), in order."""
    rng = np.random.default_rng(seed)
    dev = 1_000_000 + np.arange(n, dtype=np.int64) * period
    arr = dev + OFFSET + LATENCY + np.round(rng.normal(size=n) * 400_000).astype(np.int64)
    return dev, np.maximum.accumulate(arr)


def _stall(arr: np.ndarray, i0: int, i1: int) -> np.ndarray:
    """Samples i0..i1-1 held up until sample i1's arrival, then arriving one after another."""
    out = arr.copy()
    out[i0:i1] = arr[i1] - (i1 - i0) + np.arange(i1 - i0)
    return out


def test_a_stall_leaves_the_samples_at_their_times():
    dev, arr = _stream()
    stalled = _stall(arr, 2000, 2120)  # 600 ms held up
    assert (stalled[2000:2120] - arr[2000:2120]).max() > 590_000_000
    clock = DeviceClock()
    t = np.array([clock.host_ns(int(a), int(d)) for a, d in zip(stalled, dev, strict=True)])
    true = dev + OFFSET + LATENCY
    # after the offset has settled, every sample within a fraction of the jitter of its time
    assert np.abs(t[800:] - true[800:]).max() < 300_000
    assert np.all(np.diff(t) > 0)
    assert clock.held >= 115 and clock.restarts == 0


def test_a_held_up_first_sample_and_a_restarted_device_clock_are_followed():
    dev, arr = _stream()
    arr = arr.copy()
    arr[0] += 400_000_000  # the first sample arrived 400 ms late (the port's first read)
    dev2 = dev.copy()
    dev2[2000:] = dev[2000:] - dev[2000] + 3_000  # the device restarted: its clock from 0
    clock = DeviceClock()
    t = np.array([clock.host_ns(int(a), int(d)) for a, d in zip(arr, dev2, strict=True)])
    true = dev + OFFSET + LATENCY  # the host's view does not restart
    assert np.abs(t[800:2000] - true[800:2000]).max() < 300_000
    assert np.abs(t[2800:] - true[2800:]).max() < 300_000
    assert clock.restarts == 2  # the offset taken anew after the late first sample, and at the restart
    assert np.all(np.diff(t) >= 0)


def test_no_device_clock_is_timed_by_arrival():
    clock = DeviceClock()
    assert [clock.host_ns(a, 0) for a in (10, 25, 40)] == [10, 25, 40]


def _held_up(src, dst, t0_ns: int, t1_ns: int) -> int:
    """src with every device sample that arrived in [t0, t1) held up to t1 (its arrival stamp and
    its log time), as a stalled host delivers them; returns how many."""
    n = 0
    with McapWriter(dst) as w:
        for name, rec in read_metadata(src).items():
            w.add_metadata(name, rec)
        for r in read_messages(src):
            log_t = r.log_time_ns
            if (
                r.topic.startswith("device/")
                and hasattr(r.message, "header")
                and t0_ns <= r.message.header.stamp_ns < t1_ns
            ):
                r.message.header.stamp_ns = t1_ns + n
                log_t = t1_ns + n
                n += 1
            w.write(r.topic, r.message, log_t, r.publish_time_ns, r.sequence)
    return n


def _states(path) -> np.ndarray:
    """(stamp ns, tip x, y, z m) of every fusion/state, in order."""
    return np.array(
        [
            (r.message.header.stamp_ns, r.message.tip_m.x, r.message.tip_m.y, r.message.tip_m.z)
            for r in read_messages(path, ["fusion/state"])
        ]
    )


def test_a_host_stall_leaves_the_estimate_as_it_was(tmp_path_factory, tmp_path):
    session = bench_session(tmp_path_factory, "teleop", seed=11, duration_s=9.0)
    t_first = next(iter(read_messages(session, ["device/gyro"]))).message.header.stamp_ns
    stalled = tmp_path / "stalled.mcap"
    held = _held_up(session, stalled, t_first + 5_000_000_000, t_first + 5_600_000_000)
    assert held > 150  # gyro, accel and ToF samples of 600 ms
    outs, held_up = [], []
    for name, src in (("clean", session), ("stalled", stalled)):
        out = tmp_path / f"{name}_est.mcap"
        assert tiplog_main(["fusion", "run", str(src), "--out", str(out), "--quiet"]) == 0
        outs.append(_states(out))
        *_, diag = read_messages(out, ["fusion/diagnostics"])
        held_up.append(dict(diag.message.held_up))
    clean, stall = outs
    # counted in the diagnostics: 600 ms of gyro (200 Hz) and accelerometer samples held up
    assert held_up[0] == {} and held_up[1]["gyro"] >= 110 and held_up[1]["accel"] >= 110, held_up
    # a state at every gyro sample in both, each at its sample's time (the held-up ones too)
    assert clean.shape == stall.shape
    assert np.abs(clean[:, 0] - stall[:, 0]).max() < 100_000
    worst_mm = np.linalg.norm(clean[:, 1:] - stall[:, 1:], axis=1).max() * 1e3
    assert worst_mm < 0.05, worst_mm
