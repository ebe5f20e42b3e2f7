"""Motion protocols of the paper's experiments as commanded tip targets for the RCM servo.

Each protocol returns a `trajectory.Command` (tip targets and roll at the servo rate, trial
index and phase per sample, trial descriptions); rates are taken by the caller with central
differences (all profiles are smooth). Every protocol starts and ends at the neutral pose with
the tip at rest; trials are minimum-jerk moves about the RCM between 3 s stationary windows.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

from services.bench.robot import operator_style
from services.bench.robot.trajectory import (  # noqa: F401  (re-exported for callers)
    FREE,
    HOLD,
    MOVE,
    PHASE_NAMES,
    POST,
    PRE,
    Builder,
    Command,
    ProtocolContext,
    concat,
    min_jerk,
    oscillation,
    taper,
)

WINDOW_S = 3.0  # stationary windows before and after each trial
TRANSLATION_DEPTH_M = 0.130
ROTATION_DEPTH_M = 0.140
TRANSLATION_STEPS_MM = (1.0, 2.0, 5.0, 10.0, 20.0)
PITCH_DEG = (-25.0, -15.0, -5.0, 5.0, 15.0, 25.0)
YAW_DEG = (-11.0, -8.0, -5.0, 5.0, 15.0, 25.0)
ROLL_DEG = (-90.0, -45.0, -15.0, 15.0, 45.0, 90.0)
REPEATS = 10
# Programmed chirp sweeps: (axis, duration s, f0 Hz, f1 Hz, amplitude at f0, at f1 [mm tip or deg]).
SWEEPS = {
    "sweep_pitch": ("pitch", 137.0, 0.15, 1.6, 24.7, 3.0),
    "sweep_roll": ("roll", 102.0, 0.15, 1.6, 25.0, 3.4),
    "sweep_depth": ("depth", 120.0, 0.1, 1.0, 10.0, 6.4),
}
LATENCY_FREQS_HZ = {
    "depth": (0.1, 0.15, 0.2, 0.3, 0.5, 0.7, 1.0),
    "tilt": (0.15, 0.2, 0.3, 0.5, 0.8, 1.0, 1.3, 1.6),
    "roll": (0.15, 0.2, 0.3, 0.5, 0.8, 1.0, 1.3, 1.6),
}
TELEOP_BLOCK_S = 120.0


def translation(ctx: ProtocolContext, seed: int) -> Command:
    """300 steps of 1-20 mm along +-x, +-y, +-z of the camera frame from 130 mm depth, random order."""
    b = Builder(ctx)
    b.move([0.0, 0.0, TRANSLATION_DEPTH_M, 0.0], FREE)
    b.hold(1.0, FREE)
    p0 = b.tip(b.pose[None])[0]
    conds = [(ax, sg, mm) for ax in range(3) for sg in (-1.0, 1.0) for mm in TRANSLATION_STEPS_MM]
    order = np.random.default_rng(seed).permutation(np.repeat(np.arange(len(conds)), REPEATS))
    reps = np.zeros(len(conds), int)
    for i, ci in enumerate(order):
        ax, sg, mm = conds[ci]
        reps[ci] += 1
        d = sg * mm * 1e-3 * ctx.R_base_camera[:, ax]
        T = max(ctx.min_move_s, 1.875 * mm * 1e-3 / (ctx.speed_fraction * ctx.tip_speed_max_mps))
        s = min_jerk(b.n_of(T) + 1)[1:, None]
        pre = b.add_cart(np.repeat(p0[None], b.n_of(WINDOW_S), 0), np.zeros(b.n_of(WINDOW_S)), PRE, i)
        mv = b.add_cart(p0 + s * d, np.zeros(len(s)), MOVE, i)
        post = b.add_cart(np.repeat((p0 + d)[None], b.n_of(WINDOW_S), 0), np.zeros(b.n_of(WINDOW_S)), POST, i)
        b.add_cart(p0 + d - s * d, np.zeros(len(s)), FREE)
        b.record("translation", "xyz"[ax], sg * mm, "mm", pre, mv, post, rep=int(reps[ci]), direction_base=d.tolist())
    b.pose = np.array([0.0, 0.0, TRANSLATION_DEPTH_M, 0.0])
    b.move([0.0, 0.0, ctx.depth_m, 0.0], FREE)
    return b.build()


def rotation(ctx: ProtocolContext, seed: int) -> Command:
    """180 pitch / yaw / roll trials about the neutral shaft at 140 mm, random order."""
    b = Builder(ctx)
    base = np.array([0.0, 0.0, ROTATION_DEPTH_M, 0.0])
    b.move(base, FREE)
    b.hold(1.0, FREE)
    conds = [("pitch", a) for a in PITCH_DEG] + [("yaw", a) for a in YAW_DEG] + [("roll", a) for a in ROLL_DEG]
    order = np.random.default_rng(seed).permutation(np.repeat(np.arange(len(conds)), REPEATS))
    reps = np.zeros(len(conds), int)
    for i, ci in enumerate(order):
        axis, deg = conds[ci]
        reps[ci] += 1
        target = base.copy()
        target[{"pitch": 0, "yaw": 1, "roll": 3}[axis]] = np.deg2rad(deg)
        pre = b.hold(WINDOW_S, PRE, i)
        mv = b.move(target, MOVE, i)
        post = b.hold(WINDOW_S, POST, i)
        b.move(base, FREE)
        vec = {"pitch": ctx.a_pitch, "yaw": ctx.a_yaw, "roll": ctx.u0}[axis]
        b.record("rotation", axis, deg, "deg", pre, mv, post, rep=int(reps[ci]), axis_base=vec.tolist())
    b.move([0.0, 0.0, ctx.depth_m, 0.0], FREE)
    return b.build()


def fit_block(ctx: ProtocolContext, seed: int) -> Command:
    """Ten static poses at 140 mm, 7.8 s each (78 s): minimum-jerk move, then hold."""
    b = Builder(ctx)
    rng = np.random.default_rng(seed)
    ang = np.deg2rad(rng.uniform(-8.0, 8.0, (10, 2)))
    roll = np.deg2rad(rng.uniform(-40.0, 40.0, 10))
    for i in range(10):
        target = np.array([ang[i, 0], ang[i, 1], ROTATION_DEPTH_M, roll[i]])
        T = b.move_time(target)
        if T > 4.8:
            raise ValueError("fit block: a pose change is too large for its 7.8 s slot")
        mv = b.move(target, MOVE, i)
        hold = b.hold(7.8 - (mv[1] - mv[0]) / ctx.rate_hz, HOLD, i)
        b.record("fit_pose", "pose", 0.0, "-", (mv[0], mv[0]), mv, hold, pose=target.tolist())
    b.move([0.0, 0.0, ctx.depth_m, 0.0], FREE)
    return b.build()


def static_holds(ctx: ProtocolContext, seed: int) -> Command:
    """Twenty 30 s holds at four poses (random order), then a 5 min soak at the neutral pose."""
    b = Builder(ctx)
    L = ctx.depth_m
    poses = np.array(
        [
            [0, 0, L, 0],
            [np.deg2rad(8), 0, 0.135, np.deg2rad(30)],
            [0, np.deg2rad(-6), 0.145, 0],
            [np.deg2rad(-8), np.deg2rad(5), L, np.deg2rad(-30)],
        ]
    )
    order = np.random.default_rng(seed).permutation(np.repeat(np.arange(4), 5))
    for i, pi in enumerate(order):
        mv = b.move(poses[pi], FREE, seconds=max(2.0, b.move_time(poses[pi])))
        hold = b.hold(30.0, HOLD, i)
        b.record("hold", f"pose{pi}", 30.0, "s", (mv[0], mv[0]), mv, hold, pose=poses[pi].tolist())
    mv = b.move(poses[0], FREE, seconds=2.0)
    hold = b.hold(300.0, HOLD, len(order))
    b.record("soak", "pose0", 300.0, "s", (mv[0], mv[0]), mv, hold, pose=poses[0].tolist())
    return b.build()


def sweep(ctx: ProtocolContext, name: str) -> Command:
    """One programmed chirp sweep (exponential in frequency, amplitude falling as a power law)."""
    axis, T, f0, f1, a0, a1 = SWEEPS[name]
    b = Builder(ctx)
    n = b.n_of(T)
    t = np.arange(n) / ctx.rate_hz
    k = np.log(f1 / f0) / T
    phase = 2.0 * np.pi * f0 * (np.exp(k * t) - 1.0) / k
    f = f0 * np.exp(k * t)
    amp = a0 * (f / f0) ** (np.log(a1 / a0) / np.log(f1 / f0))
    amp = amp * (1e-3 if axis in ("pitch", "depth") else np.pi / 180.0)
    x = amp * np.sin(phase) * taper(n, b.n_of(5.0))
    pre = b.hold(WINDOW_S, PRE, 0)
    mv = oscillation(b, axis, x, 0)
    post = b.hold(WINDOW_S, POST, 0)
    b.record(name, axis, a0, "mm" if axis != "roll" else "deg", pre, mv, post, f0_hz=f0, f1_hz=f1, amp_end=a1)
    return b.build()


def latency(ctx: ProtocolContext, seed: int) -> Command:
    """Sinusoids per channel and frequency, amplitudes bounded by the tip-speed (or roll-rate) limit."""
    b = Builder(ctx)
    v = ctx.speed_fraction * ctx.tip_speed_max_mps
    caps = {"depth": 0.010, "tilt": 0.020, "roll": np.deg2rad(20.0)}
    i = 0
    for axis, freqs in LATENCY_FREQS_HZ.items():
        for fr in freqs:
            n_cyc = max(6, int(np.ceil(10.0 * fr)))
            n = b.n_of(n_cyc / fr)
            T_ramp = min(2.0, 1.0 / fr)
            w = 2.0 * np.pi * fr
            lim = ctx.roll_rate_max_radps * 0.8 if axis == "roll" else v
            amp = min(caps[axis], lim / (w + 1.875 / T_ramp))
            x = amp * np.sin(w * np.arange(n) / ctx.rate_hz) * taper(n, b.n_of(T_ramp))
            pre = b.hold(2.0, PRE, i)
            mv = oscillation(b, axis, x, i)
            post = b.hold(2.0, POST, i)
            unit = "deg" if axis == "roll" else "mm"
            mag = np.rad2deg(amp) if axis == "roll" else amp * 1e3
            b.record("latency", axis, mag, unit, pre, mv, post, freq_hz=fr)
            i += 1
    return b.build()


def _band_noise(rng: np.random.Generator, n: int, rate_hz: float, bands: tuple[tuple[float, float], ...]) -> np.ndarray:
    """Sum of low-passed Gaussian noises, each (cutoff Hz, relative SD), unit overall SD, zero mean."""
    x = np.zeros(n)
    for fc, sd in bands:
        sos = butter(2, fc, fs=rate_hz, output="sos")
        y = sosfiltfilt(sos, rng.standard_normal(n + 4000))[2000:-2000]
        x += sd * (y - y.mean()) / y.std()
    return x / x.std()


def _scale_for_fraction(mag: np.ndarray, threshold: float, target: float) -> float:
    """Scale s such that mean(s * mag < threshold) == target (bisection; the fraction falls with s)."""
    lo, hi = 1e-6, 1e3
    for _ in range(100):
        mid = np.sqrt(lo * hi)
        if np.mean(mid * mag < threshold) > target:
            lo = mid
        else:
            hi = mid
    return lo


def teleop_block(ctx: ProtocolContext, seed: int, block: int) -> Command:
    """One 120 s teleoperated-like block: smooth random targets with human-like (< 1-2 Hz) spectra,
    moved as the context's operator moves (tremor, hesitation pauses, detours; none by default).

    The envelope matches the paper's operator: depth inside the working range 85-99 % of the time
    and tilt within 10 deg of neutral 93-97 % of the time; tip speed under the limit.
    """
    v_lim = 0.95 * ctx.tip_speed_max_mps
    lo_w, hi_w = ctx.working_depth_m
    mid, half = 0.5 * (lo_w + hi_w), 0.5 * (hi_w - lo_w)
    for attempt in range(50):
        rng = np.random.default_rng([seed, block, attempt])
        b = Builder(ctx)
        n = b.n_of(TELEOP_BLOCK_S)
        bands = ((0.06, 1.0), (0.25, 0.45), (0.8, 0.08))
        tp, ty, dd, rr = (_band_noise(rng, n, ctx.rate_hz, bands) for _ in range(4))
        w = taper(n, b.n_of(6.0))
        tilt = np.hypot(tp, ty) * w
        s_t = _scale_for_fraction(tilt, ctx.tilt_envelope_rad, rng.uniform(0.935, 0.965))
        # The taper pulls the depth toward the neutral depth; centre the noise on the working range.
        depth_off = (mid - ctx.depth_m) * w
        s_d = _scale_for_fraction(np.abs(dd * w), half, rng.uniform(0.87, 0.97))
        poses = np.stack(
            [s_t * tp * w, s_t * ty * w, ctx.depth_m + depth_off + s_d * dd * w, np.deg2rad(20.0) * rr * w], axis=1
        )
        p = b.tip(poses)
        speed = np.linalg.norm(np.gradient(p, axis=0), axis=1) * ctx.rate_hz
        roll_rate = np.abs(np.gradient(poses[:, 3])) * ctx.rate_hz
        if speed.max() <= v_lim and roll_rate.max() <= ctx.roll_rate_max_radps:
            break
    else:
        raise ValueError("teleop: no block under the tip-speed limit after 50 draws")
    if ctx.operator.active:  # after the draw is accepted: the intended motion is the same operator or not
        poses = operator_style.apply(
            poses, ctx.operator, np.random.default_rng([seed, block, attempt, 1]), ctx.rate_hz, w
        )
    pre = b.hold(WINDOW_S, PRE, 0)
    mv = b.add_poses(poses, MOVE, 0)
    b.pose = np.array([0.0, 0.0, ctx.depth_m, 0.0])
    post = b.hold(WINDOW_S, POST, 0)
    b.record(f"teleop{block + 1}", "free", 0.0, "-", pre, mv, post, draw=attempt)
    return b.build()


def demo(ctx: ProtocolContext, duration_s: float = 100.0) -> Command:
    """A continuous loop (period 100 s): Lissajous tilt, slow depth and roll, from and back to neutral."""
    b = Builder(ctx)
    n = b.n_of(duration_s)
    t = np.arange(n) / ctx.rate_hz
    w = taper(n, b.n_of(min(3.0, duration_s / 3)))
    tau = 2.0 * np.pi * t
    poses = np.stack(
        [
            np.deg2rad(8.0) * np.sin(0.05 * tau) * w,
            np.deg2rad(7.0) * np.sin(0.07 * tau + 0.5) * w,
            ctx.depth_m + 0.008 * np.sin(0.03 * tau) * w,
            np.deg2rad(30.0) * np.sin(0.04 * tau) * w,
        ],
        axis=1,
    )
    mv = b.add_poses(poses, MOVE, 0)
    b.record("demo", "free", 0.0, "-", (0, 0), mv, (mv[1], mv[1]), period_s=100.0)
    return b.build()


PROTOCOLS = (
    "static", "latency", "fit", "translation", "rotation", "sweeps", "sweep_pitch", "sweep_roll", "sweep_depth",
    "teleop", "teleop1", "teleop2", "teleop3", "teleop4", "demo",
)  # fmt: skip


def build(name: str, ctx: ProtocolContext, seed: int, duration_s: float | None = None) -> Command:
    """The named protocol's command; `duration_s` only sets the demo loop's length."""
    gap = int(round(ctx.rate_hz))
    if name == "static":
        return static_holds(ctx, seed)
    if name == "latency":
        return latency(ctx, seed)
    if name == "fit":
        return fit_block(ctx, seed)
    if name == "translation":
        return translation(ctx, seed)
    if name == "rotation":
        return rotation(ctx, seed)
    if name in SWEEPS:
        return sweep(ctx, name)
    if name == "sweeps":
        return concat([sweep(ctx, s) for s in SWEEPS], gap)
    if name == "teleop":
        return concat([teleop_block(ctx, seed, i) for i in range(4)], gap)
    if name in ("teleop1", "teleop2", "teleop3", "teleop4"):
        return teleop_block(ctx, seed, int(name[-1]) - 1)
    if name == "demo":
        return demo(ctx, 100.0 if duration_s is None else duration_s)
    raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}; got {name!r}")
