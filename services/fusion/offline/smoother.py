"""Fixed-interval Rauch-Tung-Striebel smoother for archives (offline only).

One forward pass of the tracking filter over all measurements in time order (the causal
filter the live output converges to), recording at every propagation step the posterior
before it, the prior after it and the smoother gain G = P_post F^T P_prior^-1; then one
backward pass x_s(i) = x(i) (+) G(i) [x_s(i+1) (-) x_prior(i+1)], on the error-state
manifold (attitude through Exp/Log). A filter reset breaks the chain: each segment is
smoothed on its own. Covariances are not smoothed: samples carry the filter's sigmas.
"""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.filter import State
from services.fusion.eskf.kernels.propagate import transition
from services.fusion.eskf.kernels.so3 import exp_so3
from services.fusion.eskf.params import SENSORS, Params
from services.fusion.eskf.sample import StateSample, make_sample
from services.fusion.timing.runner import FusionRunner
from tiplog.calibration import Calibration
from tiplog.geometry import so3_log

_EYE = np.eye(16)


def _nominal(s: State) -> tuple:
    return (s.t_ns, s.p.copy(), s.v.copy(), s.R.copy(), s.bg.copy(), s.ba.copy(), s.brho)


class _Recorder:
    def __init__(self) -> None:
        self.post: list[tuple] = []  # posterior before each propagation step (node i)
        self.prior: list[tuple] = []  # prior after it (node i + 1)
        self.gain: list[np.ndarray] = []
        self.breaks: set[int] = set()  # node indices where a new segment starts


def smooth(calib: Calibration, params: Params, msgs, sensors: frozenset[str] = SENSORS) -> list[StateSample]:
    """Smoothed states at every gyro sample from (topic, message, arrival) inputs."""
    runner = FusionRunner(calib, params, sensors)
    filt = runner.filt
    events = []
    for topic, msg, _ in msgs:
        try:
            m = runner.adapter.measurement(topic, msg)
        except (AttributeError, TypeError, ValueError):
            continue
        if m is not None:
            events.append(runner.event(m))
    events.sort(key=lambda e: e[0])
    rec = _Recorder()
    original = filt.propagate

    def propagate(s: State, t_ns: int) -> None:
        dt = (t_ns - s.t_ns) * 1e-9
        if dt <= 0.0:
            return
        F = transition(s.R, s.bg, s.ba, s.w_imu, s.f_imu, s.alpha_tool, filt.R_ti, filt.r_imu_tip_tool, dt, filt.imu)
        P_post = s.P.copy()
        rec.post.append((*_nominal(s), P_post))
        original(s, t_ns)
        rec.prior.append(_nominal(s))
        try:
            rec.gain.append(np.linalg.solve(s.P, F @ P_post).T)  # P_post F^T P_prior^-1 (P symmetric)
        except np.linalg.LinAlgError:
            rec.gain.append(np.zeros_like(F))

    filt.propagate = propagate  # the forward pass records every step
    filt.propagate_apart = True
    gyro_nodes: list[int] = []
    track = runner._track
    for ev in events:
        before = track.state
        runner._process(ev)
        track = runner._track
        if before is not None and track.state is None or before is None and track.state is not None:
            rec.breaks.add(len(rec.post))
        if ev[1] == "gyro" and track.state is not None:
            # a zero-length step right after the gyro event: the output node is the state at
            # t_k exactly (measurements applied later without propagation belong to the next)
            s = track.state
            rec.post.append((*_nominal(s), s.P.copy()))
            rec.prior.append(_nominal(s))
            rec.gain.append(_EYE)
            gyro_nodes.append(len(rec.post) - 1)
        runner._snaps.clear()
        runner._snap_keys.clear()
        runner._done.clear()
        runner._done_keys.clear()
    if track.state is not None:
        rec.post.append((*_nominal(track.state), track.state.P.copy()))
    filt.propagate = original
    filt.propagate_apart = False
    return _backward(rec, gyro_nodes, runner, calib)


def _backward(rec: _Recorder, gyro_nodes: list[int], runner: FusionRunner, calib: Calibration) -> list[StateSample]:
    n = len(rec.post)
    smoothed: list[tuple | None] = [None] * n
    for i in range(n - 1, -1, -1):
        t, p, v, R, bg, ba, brho, P = rec.post[i]
        nxt = smoothed[i + 1] if i + 1 < n else None
        if nxt is None or (i + 1) in rec.breaks or i >= len(rec.gain):
            smoothed[i] = (t, p, v, R, bg, ba, brho, P)
            continue
        _, pp, vp, Rp, bgp, bap, brp = rec.prior[i]
        d = np.empty(16)
        d[0:3] = nxt[1] - pp
        d[3:6] = nxt[2] - vp
        d[6:9] = so3_log(Rp.T @ nxt[3])
        d[9:12] = nxt[4] - bgp
        d[12:15] = nxt[5] - bap
        d[15] = nxt[6] - brp
        dx = rec.gain[i] @ d
        smoothed[i] = (
            t, p + dx[0:3], v + dx[3:6], R @ exp_so3(dx[6:9]), bg + dx[9:12], ba + dx[12:15],
            brho + dx[15], P,
        )  # fmt: skip
    out = []
    neutral = runner._neutral()
    for i in gyro_nodes:
        if i >= n or smoothed[i] is None:
            continue
        t, p, v, R, bg, ba, brho, P = smoothed[i]
        s = State.__new__(State)
        s.t_ns, s.p, s.v, s.R, s.bg, s.ba, s.brho, s.P = t, p, v, R, bg, ba, brho, P
        s.last_vision_ns = -(1 << 62)
        out.append(make_sample(s, calib.rcm_base_m, neutral, runner.lock_ns))
    return out
