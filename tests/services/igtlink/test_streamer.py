"""The sender's schedule on a simulated clock: states at the gyro rate go out at `rate_hz`,
evenly spaced in state time; slower states all go out; a stop is INVALID after stale_after_s."""

from __future__ import annotations

import numpy as np

from services.igtlink.app import Streamer
from tests.services.igtlink.test_messages import _parse, _state


class _Server:
    connections = 1

    def __init__(self) -> None:
        self.sent: list = []

    def broadcast(self, data: bytes) -> int:
        self.sent += _parse(data)
        return 1


def _run(rate_hz: float, state_period_ms: float, seconds: float, jitter_ms: float = 0.3):
    rng = np.random.default_rng(3)
    clock = [0]
    server = _Server()
    st = Streamer(server, None, rate_hz=rate_hz, stale_after_s=0.25, status_period_s=1.0, clock=lambda: clock[0],
                  wall=lambda: 1_700_000_000_000_000_000 + clock[0])  # fmt: skip
    for k in range(int(seconds * 1e3 / state_period_ms)):
        t = int((k * state_period_ms + rng.uniform(-jitter_ms, jitter_ms)) * 1e6)
        clock[0] = t + 2_000_000  # arrives 2 ms after its stamp
        s = _state()
        s.header.stamp_ns = t
        st.on_state(s, None)
        st.tick()
    stamps = np.array([int(m.metadata["StampNs"]) for m in server.sent if m.device_name == "TipToReference"])
    return st, server, clock, stamps


def test_gyro_rate_states_go_out_at_the_configured_rate_evenly():
    _, _, _, stamps = _run(50.0, 5.0, 4.0)
    assert 199 <= len(stamps) <= 201  # 4 s at 50 Hz
    d = np.diff(stamps) * 1e-6
    assert np.all(d > 17) and np.all(d < 23), (d.min(), d.max())


def test_every_state_goes_out_when_they_come_slower_than_the_rate():
    _, _, _, stamps = _run(200.0, 10.0, 1.0)
    assert len(stamps) == 100


def test_fusion_stopping_turns_invalid_after_stale_after_s():
    st, server, clock, _ = _run(50.0, 5.0, 1.0)
    n = len(server.sent)
    clock[0] += 200_000_000  # 0.2 s without a state: still tracking
    st.tick()
    assert len(server.sent) == n
    clock[0] += 100_000_000  # 0.3 s: stale
    st.tick()
    new = server.sent[n:]
    assert {m.metadata["TransformStatus"] for m in new} == {"INVALID"}
    assert any(m.message_type == "STRING" and m.string.startswith("NOT_TRACKING") for m in new)
