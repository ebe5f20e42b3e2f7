"""Per-trial estimates of the translation and rotation protocols: the static-trial filter run
over a session, and for each trial the tip displacement and the relative rotation between its
two stationary windows (W_pre, W_post), as the paper's metric takes them.

The estimator reads the device and vision topics and the calibration only; from the session's
`trials` metadata it takes the protocol timing (window bounds) and labels, never the poses.
Window times there are milliseconds on the session clock (the header stamps' clock).

The post window's attitude is then combined with the pre window's carried across the move by
the gyro alone. Its bias is measured at both ends, as the mean rate over each window's tail,
where the tool is at rest; across the move it is the mean of a random walk pinned at the two,
moving in proportion to the walk's variance as the filter models it (`gyro_bias_rw_dps_rts`,
`gyro_bias_rw_dps_rts_per_radps`): where the tool turned, since the bias moves in motion. With
W_pre's rate alone the bias that moved during a roll trial is carried across it wrong; pinned at
both ends, the walk takes the part of it the motion explains. The causal filter
takes each window's accelerometer and vision directions as if their errors were white, so it
ends W_post on that window's own pose-locked errors (0.21 deg for the accelerometer at each
pose, about twice that in roll about a shaft 30 deg from vertical); the gyro's error across a
move grows with the angle turned (gain, mounting, the bias moving in motion) and is far smaller
for small moves. The two relative rotations are blended with weight
sigma_a^2 / (sigma_a^2 + (k theta)^2) on the gyro's (sigma_a = `relrot_absolute_deg`, k =
`relrot_gyro_per_deg`, theta the angle turned; k is the gyro's error per degree turned with
the bias pinned at both ends; see docs/fusion-live.md). The gyro link turns the
gyro's rates through the IMU mounting as the filter has learnt it by the session's end.

The mounting is learnt in the rotation protocol only, and only from a calibration that does not
state how well it knows it (`R_tool_imu_sd_deg`; `tiplog calibrate` states its fit's, which is
better than what the trials can teach). A translation trial turns the
tool by a few degrees, and the accelerometer's pose-locked errors between its two windows (0.21
deg per pose) then read as a mounting error many times larger, which the next trial takes back,
and the translation error grows. Otherwise the
calibration's mounting is held (`init_mount_deg` 0), unless the caller gives its own parameters.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from study.static_filter import StaticFilter, StaticParams, inclined_rotation, initial_heading
from tiplog import mcap_io
from tiplog.calibration import Calibration
from tiplog.geometry import rotation_angle, so3_exp, so3_log

TOF_VALID = 1
UPDATES = frozenset({"accel", "tof", "vision"})  # what can be switched off for ablations
# Timing and labels only: every other key of a trial (the bench's commanded or true poses) is
# left unread.
_TRIAL_KEYS = ("index", "kind", "axis", "magnitude", "unit", "pre_start", "pre_end", "post_start", "post_end")


@dataclass(frozen=True)
class TrialWindows:
    index: int
    kind: str
    axis: str
    magnitude: float
    unit: str
    pre_ns: tuple[int, int]
    post_ns: tuple[int, int]


@dataclass
class TrialEstimate:
    """One trial: tip displacement post - pre [m] in base and camera axes, and the relative
    rotation R_post R_pre^T (base axes) with its rotation vector [deg]."""

    windows: TrialWindows
    tip_pre_base_m: np.ndarray
    tip_post_base_m: np.ndarray
    R_pre: np.ndarray
    R_post: np.ndarray
    displacement_base_m: np.ndarray
    displacement_camera_m: np.ndarray
    R_rel: np.ndarray
    rel_rotvec_deg: np.ndarray


def trial_windows(metadata: dict[str, dict[str, str]]) -> list[TrialWindows]:
    """Protocol timing from a session's `trials` metadata; ValueError naming what is missing."""
    rec = metadata.get("trials")
    if rec is None or "json" not in rec:
        raise ValueError("session has no 'trials' metadata (protocol timing)")
    out = []
    for t in json.loads(rec["json"]):
        d = {k: t.get(k) for k in _TRIAL_KEYS}
        if d["pre_start"] is None or d["post_end"] is None:
            continue
        ms = 1_000_000
        out.append(
            TrialWindows(
                int(d["index"]),
                str(d["kind"]),
                str(d["axis"]),
                float(d["magnitude"]),
                str(d["unit"]),
                (int(d["pre_start"] * ms), int(d["pre_end"] * ms)),
                (int(d["post_start"] * ms), int(d["post_end"] * ms)),
            )
        )
    return out


def _events(path: str | Path, calib: Calibration) -> list[tuple[int, int, Any]]:
    """(latency-corrected time [ns], kind order, payload), sorted; kinds 0 gyro, 1 accel,
    2 tof, 3 vision."""
    ev: list[tuple[int, int, Any]] = []
    lat = {k: calib.latency_ns(k) for k in ("gyro", "accel", "tof", "camera")}
    for r in mcap_io.read_messages(path, ["device/gyro", "device/accel", "device/tof", "vision/observation"]):
        m = r.message
        if r.topic == "device/gyro":
            v = m.rate_radps
            ev.append((m.header.stamp_ns - lat["gyro"], 0, np.array([v.x, v.y, v.z])))
        elif r.topic == "device/accel":
            v = m.specific_force_mps2
            ev.append((m.header.stamp_ns - lat["accel"], 1, np.array([v.x, v.y, v.z])))
        elif r.topic == "device/tof":
            if m.status == TOF_VALID and 20.0 <= m.range_raw_mm <= 400.0:
                ev.append((m.header.stamp_ns - lat["tof"], 2, m.range_raw_mm * 1e-3))
        elif m.accepted:
            nl, nr, ray = m.n_left, m.n_right, m.junction_ray
            obs = (
                np.array([nl.x, nl.y, nl.z]),
                np.array([nr.x, nr.y, nr.z]),
                np.array([ray.x, ray.y, ray.z]) if m.junction_visible else None,
            )
            ev.append((m.header.stamp_ns - lat["camera"], 3, obs))
    ev.sort(key=lambda e: (e[0], e[1]))
    return ev


def _mean_rotation(Rs: list[np.ndarray]) -> np.ndarray:
    """Chordal mean of rotation matrices (projection of the arithmetic mean onto SO(3))."""
    U, _, Vt = np.linalg.svd(np.mean(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.linalg.det(U @ Vt)])
    return U @ D @ Vt


def gyro_link(
    t_ns: np.ndarray,
    w_imu: np.ndarray,
    t0: int,
    t1: int,
    bias: np.ndarray,
    bias_end: np.ndarray | None = None,
    walk: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """The IMU's rotation from t0 to t1 [ns] by the gyro alone (rates held over each sample
    interval, the bias removed): R_imu(t0)^T R_imu(t1).

    The bias is `bias` throughout, or, given `bias_end` (the bias at t1), the mean of a random
    walk pinned at both ends: it moves from `bias` to `bias_end` in proportion to the walk's
    variance accumulated so far, at `walk` = (a, c) [rad/s/sqrt(s), per rad/s of rate] the
    rate a^2 + (c |w|)^2, so a bias that moves in motion moves where the tool turned."""
    k = np.flatnonzero((t_ns > t0) & (t_ns <= t1))
    R = np.eye(3)
    if len(k) < 2:
        return R
    dt = np.diff(t_ns[k]) * 1e-9
    w = w_imu[k[:-1]] - bias
    if bias_end is not None:
        a, c = walk
        rate = a**2 + (c * np.linalg.norm(w, axis=1)) ** 2
        acc = np.cumsum(rate * dt)
        if acc[-1] > 0:
            w = w - np.outer((acc - 0.5 * rate * dt) / acc[-1], np.asarray(bias_end) - bias)  # mid-interval
    for wi, dti in zip(w, dt, strict=True):
        R = R @ so3_exp(wi * dti)
    return R


def _blend_gyro(
    Rp: np.ndarray,
    Rq: np.ndarray,
    t_ns: np.ndarray,
    w_imu: np.ndarray,
    t0: int,
    t1: int,
    bias: np.ndarray,
    R_tool_imu: np.ndarray,
    prm: StaticParams,
    bias_end: np.ndarray | None = None,
) -> np.ndarray:
    """W_post's attitude blended with W_pre's carried by the gyro (see the module docstring);
    `bias_end`: the bias at rest in W_post, the walk's other end."""
    walk = (np.radians(prm.gyro_bias_rw_dps_rts), np.radians(prm.gyro_bias_rw_dps_rts_per_radps))
    G = R_tool_imu @ gyro_link(t_ns, w_imu, t0, t1, bias, bias_end, walk) @ R_tool_imu.T
    theta_deg = float(np.degrees(rotation_angle(G)))
    sa2 = prm.relrot_absolute_deg**2
    weight = sa2 / (sa2 + (prm.relrot_gyro_per_deg * theta_deg) ** 2) if sa2 > 0 else 0.0
    return Rq @ so3_exp(weight * so3_log(Rq.T @ (Rp @ G)))


def estimate_trials(
    path: str | Path,
    calibration: Calibration | None = None,
    params: StaticParams | None = None,
    window_tail: float = 0.9,
    updates: frozenset[str] = UPDATES,
) -> tuple[list[TrialEstimate], dict[str, int]]:
    """Run the static-trial filter over a translation or rotation session. Each window's
    estimate is the mean over its last `window_tail` fraction (the causal filter has then seen
    most of the window). `updates` switches measurement streams off for ablations (the gyro
    always propagates; without vision the heading starts at 0, as nothing observes it).
    Returns the per-trial estimates and the filter's update counts."""
    unknown = set(updates) - UPDATES
    if unknown:
        raise ValueError(f"updates: unknown stream(s) {', '.join(sorted(unknown))} (choose from accel, tof, vision)")
    md = mcap_io.read_metadata(path)
    calib = calibration or Calibration.from_mcap_metadata(md, where=str(path))
    trials = trial_windows(md)
    if not trials:
        raise ValueError(f"{path}: no complete trial in the session")
    ev = _events(path, calib)
    t_ev = np.array([e[0] for e in ev], dtype=np.int64)
    if params is None and (calib.R_tool_imu_sd_deg is not None or all(w.kind != "rotation" for w in trials)):
        params = StaticParams(init_mount_deg=0.0)  # the mounting held: see the module docstring
    filt = StaticFilter(calib, params)
    a0, a1 = trials[0].pre_ns
    in_w = (t_ev >= a0) & (t_ev <= a1)
    f_mean = np.mean([e[2] for e, w in zip(ev, in_w, strict=True) if w and e[1] == 1], axis=0)
    normals = np.array([[e[2][0], e[2][1]] for e, w in zip(ev, in_w, strict=True) if w and e[1] == 3])
    if "vision" not in updates:
        R0 = inclined_rotation(f_mean, calib.R_tool_imu)
    elif len(normals) == 0:
        raise ValueError(f"{path}: no accepted vision frame in the first stationary window; heading unknown")
    else:
        R0, _ = initial_heading(calib, f_mean, normals)
    tofs = [e[2] for e, w in zip(ev, in_w, strict=True) if w and e[1] == 2]
    L0 = filt.depth_from_tof(R0, float(np.median(tofs))) if tofs and "tof" in updates else 0.14
    s = filt.new_state(a0, R0, L0)
    # windows as (start, end, trial index, which); collect states at gyro samples inside
    bounds = sorted(
        [(w.pre_ns[0], w.pre_ns[1], i, 0) for i, w in enumerate(trials)]
        + [(w.post_ns[0], w.post_ns[1], i, 1) for i, w in enumerate(trials)]
    )
    got: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray]]] = {}
    bias_rest: dict[tuple[int, int], list[np.ndarray]] = {}  # gyro rates in each window's tail: at rest, the bias
    b = 0
    start = int(np.searchsorted(t_ev, a0))
    for t, kind, payload in ev[start:]:
        while b < len(bounds) and t > bounds[b][1]:
            b += 1
        if b >= len(bounds):
            break
        lo, hi, i, which = bounds[b]
        filt.still = lo <= t <= hi
        if kind == 0:
            filt.on_gyro(s, t, payload)
            tail_lo = hi - window_tail * (hi - lo)
            if t >= tail_lo and filt.still:
                got.setdefault((i, which), []).append((s.tip(calib.rcm_base_m), s.R.copy()))
                bias_rest.setdefault((i, which), []).append(np.asarray(payload, float))
        else:
            filt.propagate(s, t)
            if kind == 1 and "accel" in updates:
                filt.update_accel(s, payload)
            elif kind == 2 and "tof" in updates:
                filt.update_tof(s, payload)
            elif kind == 3 and "vision" in updates:
                filt.update_vision(s, *payload)
    A = calib.R_base_camera.T
    gyro_t = np.array([e[0] for e in ev if e[1] == 0], dtype=np.int64)
    gyro_w = np.array([e[2] for e in ev if e[1] == 0], dtype=float).reshape(-1, 3)
    mounting = filt.R_tool_imu(s)  # as estimated at the session's end
    out = []
    for i, w in enumerate(trials):
        pre, post = got.get((i, 0)), got.get((i, 1))
        if not pre or not post:
            continue
        tp, tq = np.mean([x[0] for x in pre], 0), np.mean([x[0] for x in post], 0)
        Rp, Rq = _mean_rotation([x[1] for x in pre]), _mean_rotation([x[1] for x in post])
        if (i, 0) in bias_rest:
            b_pre = np.mean(bias_rest[(i, 0)], 0)
            b_post = np.mean(bias_rest[(i, 1)], 0) if filt.p.relrot_bias_end and (i, 1) in bias_rest else None
            Rq = _blend_gyro(Rp, Rq, gyro_t, gyro_w, w.pre_ns[1], w.post_ns[0], b_pre, mounting, filt.p, b_post)
        Rrel = Rq @ Rp.T
        out.append(TrialEstimate(w, tp, tq, Rp, Rq, tq - tp, A @ (tq - tp), Rrel, np.degrees(so3_log(Rrel))))
    return out, dict(s.counts)
