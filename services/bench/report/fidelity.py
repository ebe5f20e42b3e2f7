"""Fidelity report: a session's raw-sensor statistics beside the paper's.

Everything is computed from the MCAP file alone: the sensor topics, the ground truth it
carries (bench/robot) and its evaluation-only metadata (calibration_truth; the trocar gate
uses calibration_as_calibrated, as the estimator would). Each row: the paper's value and
range, the session's value, PASS/FAIL (inside the range) or n/a (the session does not
exercise it, e.g. no motion in a static session).
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.stats import chi2

from services.bench.report.data import Session, cluster_poses, in_window, load, pose_key, rest_windows, truth_p, truth_R
from services.bench.report.motion import FREE_MOTION_PROTOCOLS, motion_rows
from services.bench.report.rows import REST_MMPS, Row, _row, tip_speed_mmps
from services.bench.scenario import TofConfig
from tiplog.geometry import so3_exp, so3_log
from tiplog.geometry import vision as vg

G = 9.80665


# --- statistics ---------------------------------------------------------------------------
def accel_rows(s: Session, wins) -> list[Row]:
    a = s.streams["accel"]
    tilt_sd, dir_err, norms, norm_se, poses = [], [], [], [], []
    for w in wins:
        m = in_window(a["t"], w)
        if m.sum() < 50:
            continue
        v = a["v"][m]
        mean = v.mean(0)
        e = mean / np.linalg.norm(mean)
        b1 = np.cross(e, [1.0, 0, 0] if abs(e[0]) < 0.9 else [0, 1.0, 0])
        b1 /= np.linalg.norm(b1)
        b2 = np.cross(e, b1)
        vn = v / np.linalg.norm(v, axis=1, keepdims=True)
        tilt_sd.append(np.degrees(np.sqrt(0.5 * ((vn @ b1).var() + (vn @ b2).var()))))
        tm = np.array([(w[0] + w[1]) // 2])
        R_imu = truth_R(s, tm)[0] @ s.truth.R_tool_imu
        g_imu = R_imu.T @ np.array([0, 0, 1.0])
        dir_err.append(np.degrees(np.arccos(np.clip(e @ g_imu, -1, 1))))
        norms.append(np.linalg.norm(mean))
        norm_se.append(np.linalg.norm(v, axis=1).std(ddof=1) / np.sqrt(len(v)))
        poses.append(pose_key(s, tm))
    med = float(np.median(tilt_sd)) if tilt_sd else None
    note = f"{len(tilt_sd)} windows, {min(tilt_sd):.2f}-{max(tilt_sd):.2f}" if tilt_sd else "no rest windows"
    rows = [_row("accel tilt SD per sample at rest", "deg", "0.30-0.55", 0.30, 0.55, med, note)]
    # pose-locked: one value per distinct pose (windows of one pose share their error)
    npose, rms = 0, None
    if dir_err:
        labels = cluster_poses(np.asarray(poses))
        per_pose = [np.mean(np.asarray(dir_err)[labels == k]) for k in range(labels.max() + 1)]
        npose = len(per_pose)
        rms = float(np.sqrt(np.mean(np.square(per_pose)))) if npose >= 5 else None
    rows.append(
        _row("accel pose-locked direction error", "deg", "0.21 held out", 0.14, 0.30, rms, f"RMS over {npose} poses")
    )
    dev = float(abs(np.median(norms) / G - 1.0) * 100) if norms else None
    se = _median_se(np.asarray(norm_se) / G * 100)
    rows.append(_se_row(("accel norm minus g at rest", "%", "within 0.06 (self-recal off)", 0.0, 0.06), dev, se, ""))
    return rows


def tof_rows(s: Session, wins) -> list[Row]:
    d = s.streams["tof"]
    valid = d["s"] == 1
    sds, sd_se, errs, poses, Rs, ps = [], [], [], [], [], []
    for w in wins:
        m = in_window(d["t"], w) & valid
        if m.sum() < 50:
            continue
        sds.append(d["v"][m].std())
        sd_se.append(sds[-1] / np.sqrt(2.0 * (m.sum() - 1)))
        tm = np.array([(w[0] + w[1]) // 2])
        R, p = truth_R(s, tm), truth_p(s, tm)
        errs.append(d["v"][m].mean() - s.truth.tof_range_m(R, p)[0] * 1e3)
        poses.append(pose_key(s, tm))
        Rs.append(R[0])
        ps.append(p[0])
    med = float(np.median(sds)) if sds else None
    rows = [
        _se_row(("ToF SD per sample at rest", "mm", "2.95-3.43", 2.95, 3.43), med, _median_se(np.asarray(sd_se)), "")
    ]
    rep = across = None
    rep_dof, n_eff = 0, 0.0
    if len(errs) >= 4:
        E = np.asarray(errs)
        labels = cluster_poses(np.asarray(poses))
        groups = [E[labels == k] for k in range(labels.max() + 1)]
        within = [g - g.mean() for g in groups if len(g) >= 2]
        if within:
            rep_dof = sum(len(g) - 1 for g in within)
            rep = float(np.sqrt(sum((g**2).sum() for g in within) / rep_dof))
        means = np.array([g.mean() for g in groups])
        across = float(means.std(ddof=1)) if len(means) >= 3 else None
        first = [int(np.flatnonzero(labels == k)[0]) for k in range(len(groups))]
        n_eff = _independent_poses(s, np.asarray(Rs)[first], np.asarray(ps)[first])
    rows.append(
        _sd_row(("ToF repeat scatter, one pose", "mm", "0.43", 0.25, 0.65), rep, rep_dof, "window means vs truth")
    )
    npose = 0 if across is None else len(means)
    r = _row("ToF scatter across poses", "mm", "3.04", 2.0, 4.5, across, f"{npose} poses")
    if r.value is not None:
        r.note += f", {n_eff:.1f} independent"
        if n_eff < 10:
            r.status, r.note = "info", r.note + ": too few to measure a scatter (poses within the error's correlation)"
    rows.append(r)
    return rows


def _independent_poses(s: Session, R: np.ndarray, p: np.ndarray) -> float:
    """The effective number of independent poses among these (R (n, 3, 3), p (n, 3) m) for the
    ToF's pose-locked error: n^2 / sum(rho^2) with the squared-exponential correlation of the
    session's scenario (`tof.pose_corr_deg`, `tof.pose_corr_m`, as `PoseField` draws it). Poses
    a few millimetres apart share most of their error, so their scatter says little of the field's
    SD (the paper's 3.04 mm is across distinct poses)."""
    tof = (yaml.safe_load(s.meta.get("scenario", {}).get("yaml", "")) or {}).get("tof", {})
    corr_rad = np.radians(float(tof.get("pose_corr_deg", TofConfig().pose_corr_deg)))
    corr_m = float(tof.get("pose_corr_m", TofConfig().pose_corr_m))
    dR = ((R[:, None] - R[None]) ** 2).sum((2, 3))
    dp = ((p[:, None] - p[None]) ** 2).sum(2)
    rho = np.exp(-0.5 * (dR / (2.0 * corr_rad**2) + dp / corr_m**2))
    return float(len(R) ** 2 / (rho**2).sum())


def _lag_ms(
    t_meas: np.ndarray, y: np.ndarray, truth_fn, lo: float = 0.0, hi: float = 120.0, corr: float = 1.0
) -> tuple[float, float] | None:
    """(lag, standard error) [ms] minimising mean |y(t) - truth(t - lag)|^2 (grid, then a
    parabola). SE from the cost's curvature: var = 2 C0 / (N_eff C''), N_eff = N / corr."""
    if len(t_meas) < 200 or np.std(y) < 1e-9:
        return None

    def cost(lags: np.ndarray) -> np.ndarray:
        out = []
        for L in lags:
            r = y - truth_fn(t_meas - L * 1e6)
            out.append(np.mean((r - r.mean(0)) ** 2))
        return np.asarray(out)

    coarse = np.arange(lo, hi, 1.0)
    best = coarse[int(np.argmin(cost(coarse)))]
    step = 0.1
    lags = np.arange(best - 3.0, best + 3.0001, step)
    c = cost(lags)
    k = int(np.clip(np.argmin(c), 1, len(c) - 2))
    c0, c1, c2 = c[k - 1 : k + 2]
    den = c0 - 2 * c1 + c2
    if den <= 0:
        return float(lags[k]), float("nan")
    curv = den / step**2
    se = float(np.sqrt(2 * c1 / (len(t_meas) / corr * curv)))
    return float(lags[k] + 0.5 * (c0 - c2) / den * step), se


def _interp_cols(t: np.ndarray, tt: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t, tt, y[:, j]) for j in range(y.shape[1])], -1)


def latency_rows(s: Session) -> list[Row]:
    """Lag of each stream's arrival stamps behind the truth, fitted over the whole session.
    Graded on the latency and sweep protocols (periodic motion, as the paper's lock-in); on
    broadband motion the pose-locked errors bias the fit, so the value is shown as info."""
    if len(s.robot_t) < 10 or np.ptp(s.robot_p, axis=0).max() < 2e-3:
        return [_row(f"{n} latency", "ms", p, lo, hi, None, "no motion") for n, p, lo, hi in _LAT]
    dt = np.diff(s.robot_t).mean() * 1e-9
    w_tool = so3_log(np.einsum("nji,njk->nik", s.robot_R[:-1], s.robot_R[1:])) / dt
    tw = (s.robot_t[:-1] + s.robot_t[1:]) / 2
    p_imu = s.robot_p + s.robot_R @ s.truth.p_imu_tool_m
    acc = np.gradient(np.gradient(p_imu, dt, axis=0), dt, axis=0)
    g, a, tof = s.streams["gyro"], s.streams["accel"], s.streams["tof"]
    w_imu = w_tool @ s.truth.R_tool_imu  # R_tool_imu^T w
    f_imu = np.einsum("nji,nj->ni", s.robot_R @ s.truth.R_tool_imu, acc - np.array([0, 0, -G]))
    out = {}
    out["gyro"] = _lag_ms(g["t"], g["v"], lambda t: _interp_cols(t, tw, w_imu))
    out["accel"] = _lag_ms(a["t"], a["v"], lambda t: _interp_cols(t, s.robot_t, f_imu))
    rho = s.truth.tof_range_m(s.robot_R, s.robot_p) * 1e3
    ok = tof["s"] == 1
    out["ToF raw"] = _lag_ms(tof["t"][ok], tof["v"][ok], lambda t: np.interp(t, s.robot_t, rho))
    sv = tof["sv"].astype(bool)
    out["ToF smoothed"] = _lag_ms(
        tof["t"][sv], tof["sm"][sv], lambda t: np.interp(t, s.robot_t, rho), 20.0, 120.0, corr=5.0
    )
    v = s.vision
    if len(v["t"]) > 50:
        A = s.truth.T_base_camera[:3, :3].T
        c = s.truth.T_base_camera[:3, 3]
        J = s.robot_p - s.truth.junction_proximal_m * s.robot_R[:, :, 2]
        Jc = (J - c) @ A.T
        fx, fy, cx, cy = (s.truth.intrinsics[k] for k in ("fx", "fy", "cx", "cy"))
        ju = fx * Jc[:, 0] / Jc[:, 2] + cx
        m = v["jvis"].astype(bool)
        out["camera"] = _lag_ms(v["t"][m], v["ju"][m], lambda t: np.interp(t, s.robot_t, ju))
    else:
        out["camera"] = None
    graded = s.meta.get("session", {}).get("protocol", "") in ("latency", "sweeps") or "sweep" in s.meta.get(
        "session", {}
    ).get("protocol", "")
    rows = []
    for n, p, lo, hi in _LAT:
        if out[n] is None:
            rows.append(_row(f"{n} latency", "ms", p, lo, hi, None, "too little motion"))
            continue
        lag, se = out[n]
        r = _row(f"{n} latency", "ms", p, lo, hi, lag, f"fit against truth, SE {se:.2f} ms")
        if r.status == "FAIL" and np.isfinite(se) and lo - 2 * se <= lag <= hi + 2 * se:
            r.status, r.note = "PASS", r.note + " (within 2 SE)"
        rows.append(r)
    if not graded:
        for r in rows:
            if r.value is not None:
                r.status, r.note = "info", "not a latency/sweep protocol: fit for information only"
    return rows


_LAT = [
    ("gyro", "6.6-6.9", 6.6, 6.9),
    ("accel", "6.6-6.9", 6.6, 6.9),
    ("ToF raw", "9.0", 8.5, 9.5),
    ("ToF smoothed", "58.7", 56.7, 60.7),
    ("camera", "15.5-17.3", 15.5, 17.3),
]


DRIFT_BLOCK_S = 1.0  # blocks over which the gyro's bias about the shaft is averaged
PAPER_DRIFT_DEG, PAPER_DRIFT_S = 89.0, 102.0
# |N(0, sigma)| has 95 % of its mass between 0.031 sigma and 2.24 sigma: one draw of 89 deg is
# consistent with a bias wander whose RMS drift over 102 s lies between 89/2.24 and 89/0.031.
_ABS_NORMAL_95 = (0.0313, 2.2414)


def _block_bias_about_shaft(s: Session, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Per block of DRIFT_BLOCK_S over [t0, t1] ns: the gyro's mean error about the shaft [rad/s]
    and the true mean rate vector (tool frame) [rad/s]; and the drift of the whole interval integrated from the first
    true attitude [rad] with its duration [s]."""
    g = s.streams["gyro"]
    tt = g["t"] - s.truth.latency_ms["gyro"] * 1e6
    m = (tt >= t0) & (tt <= t1)
    tt, w_tool = tt[m], g["v"][m] @ s.truth.R_tool_imu.T  # the sensor's own error, not the mounting fit's
    dts = np.diff(tt, append=tt[-1]) * 1e-9
    steps = so3_exp(w_tool * dts[:, None])
    edges = np.arange(tt[0], tt[-1], DRIFT_BLOCK_S * 1e9)
    starts = set(np.searchsorted(tt, edges).tolist())
    R = R_block = truth_R(s, tt[:1])[0]
    k0 = 0
    bias, rate = [], []
    for k, S in enumerate(steps):
        if k in starts and k > k0:
            Ra, Rb = truth_R(s, tt[[k0, k]])
            span = (tt[k] - tt[k0]) * 1e-9
            bias.append(so3_log(Rb.T @ R_block)[2] / span)  # R_block: from the block's true start
            rate.append(so3_log(Ra.T @ Rb) / span)
            R_block, k0 = Rb, k
        R = R @ S
        R_block = R_block @ S
    drift = so3_log(truth_R(s, tt[-1:])[0].T @ R)[2]
    return np.asarray(bias), np.asarray(rate), float(drift), float((tt[-1] - tt[0]) * 1e-9)


def gyro_drift_row(s: Session) -> Row:
    """The gyro bias's wander about the shaft in the roll sweep, as the RMS drift it gives over the
    paper's 102 s, graded on whether the paper's one draw (89 deg) is a plausible draw of it.

    The paper integrated its gyro over one roll sweep once; a random-walk bias integrated over a
    sweep gives a drift whose size varies by a factor of tens between draws, so one session's
    drift (in the note) says little. The wander is measured instead from 1 s blocks of the bias
    about the shaft (gyro minus the true rate, the scale error regressed out): the variance of
    successive block means' differences is q^2 * 2/3 s for a random walk of density q, and the
    integrated walk's RMS over T is q T^1.5 / sqrt(3)."""
    spec = ("gyro bias wander about the shaft, roll sweep", "deg", "89 over 102 s (one draw)")
    lo, hi = PAPER_DRIFT_DEG / _ABS_NORMAL_95[1], PAPER_DRIFT_DEG / _ABS_NORMAL_95[0]
    roll = [t for t in s.trials if "roll" in str(t.get("kind", "")) and "sweep" in str(t.get("kind", ""))]
    if not roll:
        return _row(*spec, lo, hi, None, "no roll sweep")
    tr = roll[0]
    t0, t1 = tr["move_start"] / s.motion_rate_hz * 1e9, tr["move_end"] / s.motion_rate_hz * 1e9
    bias, rate, drift, dur = _block_bias_about_shaft(s, t0, t1)
    if len(bias) < 10:
        return _row(*spec, lo, hi, None, f"roll sweep of {dur:.0f} s: too short")
    db, dr = np.diff(bias), np.diff(rate, axis=0)
    coef = np.linalg.lstsq(dr, db, rcond=None)[0]  # scale and cross-axis errors' share of the differences
    q2 = max(float(np.mean((db - dr @ coef) ** 2)) / (2.0 / 3.0 * DRIFT_BLOCK_S), 0.0)
    rms = np.degrees(np.sqrt(q2) * PAPER_DRIFT_S**1.5 / np.sqrt(3.0))
    note = (
        f"q {np.degrees(np.sqrt(q2)):.3f} deg/s/sqrt(s) over {len(bias)} blocks; "
        f"this draw {abs(np.degrees(drift)):.1f} deg over {dur:.0f} s; "
        f"89 is a 95 % draw of RMS {lo:.0f}-{hi:.0f}"
    )
    return _row(*spec, lo, hi, rms, note)


def _sd_row(spec: tuple, sd: float | None, dof: int, note: str) -> Row:
    """A standard deviation from `dof` degrees of freedom: PASS also where the range meets its 95 %
    chi-square interval (a few rest windows estimate a scatter to tens of per cent)."""
    r = _row(*spec, sd, note)
    if sd is not None and dof > 0:
        lo_ci = sd * np.sqrt(dof / chi2.ppf(0.975, dof))
        hi_ci = sd * np.sqrt(dof / chi2.ppf(0.025, dof))
        r.note += f", {dof} dof, 95 % {lo_ci:.3f}-{hi_ci:.3f}"
        if r.status == "FAIL" and lo_ci <= r.hi and hi_ci >= r.lo:
            r.status, r.note = "PASS", r.note + " (within its interval)"
    return r


def _median_se(se: np.ndarray) -> float | None:
    """Standard error of the median of k window statistics, each with its own sampling standard
    error se (k,): sqrt(pi / 2) times their mean over sqrt(k), as for normal samples."""
    return float(np.sqrt(np.pi / 2) * se.mean() / np.sqrt(len(se))) if len(se) else None


def _se_row(spec: tuple, value: float | None, se: float | None, note: str, se_fmt: str = "{:.3g}") -> Row:
    """A statistic with its sampling standard error: PASS also within 2 SE of the range (a few
    2 s rest windows of a teleoperated session estimate a 0.06 % norm or a 3 mm scatter to a few
    per cent; the paper's holds were 30 s)."""
    r = _row(*spec, value, note)
    if value is not None and se is not None:
        r.note = (r.note + ", " if r.note else "") + "SE " + se_fmt.format(se)
        if r.status == "FAIL" and r.lo - 2 * se <= value <= r.hi + 2 * se:
            r.status, r.note = "PASS", r.note + " (within 2 SE)"
    return r


def _rate_row(spec: tuple, pct: float | None, n: int, note: str) -> Row:
    """A percentage over n frames, with its binomial standard error (`_se_row`)."""
    se = None if pct is None else 100.0 * np.sqrt(max(pct / 100 * (1 - pct / 100), 1e-4) / n)
    return _se_row(spec, pct, se, note, "{:.1f} %")


GROSS_JUNCTION_MM = 5.0
MIN_RESIDUAL_POSES = 5  # distinct rest poses for the held-out residual rows (as the accel's pose-locked row)


def _rest_poses(s: Session, wins) -> int:
    """Distinct poses among the session's rest windows."""
    if not wins:
        return 0
    keys = np.asarray([pose_key(s, np.array([(w[0] + w[1]) // 2])) for w in wins])
    return int(cluster_poses(keys).max() + 1)


def vision_rows(s: Session, wins) -> list[Row]:
    v = s.vision
    na = [
        ("vision tangent-plane residual", "deg", "0.11 held out", 0.08, 0.15),
        ("vision junction depth residual", "mm", "0.47 held out", 0.35, 0.60),
        ("vision tip offset (junction to tip)", "mm", "about 4", 3.0, 5.0),
        ("vision acceptance, free motion", "%", "64-78", 64.0, 78.0),
        ("trocar-gate pass, free motion", "%", "14-44", 14.0, 44.0),
        ("vision processing time", "ms", "about 113", 100.0, 126.0),
    ]
    if len(v["t"]) < 20:
        return [_row(*x, None, "no vision observations") for x in na]
    tc = v["t"] - s.truth.latency_ms["camera"] * 1e6
    R = truth_R(s, tc)
    p = truth_p(s, tc)
    A = s.truth.T_base_camera[:3, :3].T
    c = s.truth.T_base_camera[:3, 3]
    u = R[:, :, 2] @ A.T
    acc_all = v["acc"].astype(bool)
    # the paper's residuals are held out on static trials: graded on the frames at rest
    rest = tip_speed_mmps(s, tc) < REST_MMPS
    at_rest = int((acc_all & rest).sum()) >= 20
    acc = acc_all & rest if at_rest else acc_all
    where = f"{acc.sum()} accepted frames " + ("at rest" if at_rest else "(none at rest: all)")
    res = np.degrees(np.arcsin(np.clip(np.concatenate([(v["nl"] * u).sum(1)[acc], (v["nr"] * u).sum(1)[acc]]), -1, 1)))
    res = res[np.abs(res) < 1.0]  # gross errors (wrong segmentations) are the trocar gate's business
    plane = float(np.sqrt(np.mean(res**2))) if len(res) else None
    tip_c = (p - c) @ A.T
    p0 = vg.closest_axis_point(tip_c, u)
    jm = acc & v["jvis"].astype(bool)
    fx, fy, cx, cy = (s.truth.intrinsics[k] for k in ("fx", "fy", "cx", "cy"))
    ray = np.stack([(v["ju"] - cx) / fx, (v["jv"] - cy) / fy, np.ones(len(tc))], -1)
    s_j, _, _ = vg.ray_axis_intersection(ray[jm], p0[jm], u[jm])
    s_tip = ((tip_c - p0) * u).sum(1)[jm]
    off = (s_tip - s_j) * 1e3
    # gross junction errors (the wrong end of the shaft, 5-25 mm) are the trocar gate's
    # business, as gross plane errors are above: 5 mm is ten times the paper's residual
    gross = np.abs(off - np.median(off)) > GROSS_JUNCTION_MM if len(off) else np.zeros(0, bool)
    off = off[~gross]
    depth_rms = float(np.std(off)) if len(off) > 5 else None
    offset = float(np.mean(off)) if len(off) > 5 else None
    ph = s.robot_phase[np.clip(np.searchsorted(s.robot_t, tc), 0, len(s.robot_t) - 1)]
    free = np.isin(ph, ("free", "move"))
    Ac = s.calib.T_base_camera[:3, :3].T
    rcm_c = (s.calib.rcm_base_m - s.calib.T_base_camera[:3, 3]) @ Ac.T
    _, gate = vg.trocar_gate(v["nl"], v["nr"], s.calib.shaft_radius_m, rcm_c)
    nfree = int(free.sum())
    acc_rate = 100.0 * acc_all[free].mean() if nfree > 30 else None
    gate_rate = 100.0 * (acc_all & gate)[free].mean() if nfree > 30 else None
    note = f"{nfree} free-motion frames"
    rates = [
        _rate_row(na[3], acc_rate, nfree, note),
        _rate_row(na[4], gate_rate, nfree, note + "; as-calibrated RCM and hand-eye"),
    ]
    # the paper's rates are of its dynamic blocks (sweeps and teleoperation), not of the moves
    # between a static protocol's holds
    if s.meta.get("session", {}).get("protocol", "") not in FREE_MOTION_PROTOCOLS:
        for r in rates:
            if r.value is not None:
                r.status, r.note = "info", r.note + "; graded on free motion (the paper's dynamic session) only"
    residuals = [
        _row(*na[0], plane, where),
        _row(*na[1], depth_rms, f"about the mean offset; {where}; {int(gross.sum())} gross (> 5 mm) left out"),
    ]
    # the paper's held-out residuals are across the static protocol's poses, and vision's error
    # is mostly pose-locked: frames at rest at one or two poses (a dynamic session's neutral
    # holds) hold one draw of it, and the junction's draw is in the mean offset
    npose = _rest_poses(s, wins)
    if at_rest and npose < MIN_RESIDUAL_POSES:
        for r in residuals:
            if r.value is not None:
                r.status, r.note = (
                    "info",
                    r.note + f"; at rest at {npose} pose(s) only: graded over {MIN_RESIDUAL_POSES} or more",
                )
    return [
        *residuals,
        _row(*na[2], offset),
        *rates,
        _row(*na[5], float(np.median(v["proc"]))),
    ]


def mag_row(s: Session) -> Row:
    a, mg = s.streams["accel"], s.streams["mag"]
    changes = []
    rate = s.motion_rate_hz
    for tr in s.trials:
        if tr.get("kind") not in ("rotation", "translation", "fit", "static"):
            continue
        ang = []
        for k0, k1 in (("pre_start", "pre_end"), ("post_start", "post_end")):
            w = (tr[k0] / rate * 1e9 + 5e8, tr[k1] / rate * 1e9 - 5e8)
            ma, mm = in_window(a["t"], w), in_window(mg["t"], w)
            if ma.sum() < 20 or mm.sum() < 10:
                break
            ea, em = a["v"][ma].mean(0), mg["v"][mm].mean(0)
            ang.append(np.degrees(np.arccos(ea @ em / np.linalg.norm(ea) / np.linalg.norm(em))))
        if len(ang) == 2:
            changes.append(abs(ang[1] - ang[0]))
    val = float(np.max(changes)) if len(changes) >= 10 else None
    r = _row(
        "mag field-to-gravity angle change, max over trials",
        "deg",
        "up to 4.8",
        2.0,
        8.0,
        val,
        f"{len(changes)} trials",
    )
    turn = _largest_trial_turn_deg(s)
    if r.value is not None and turn < MAG_MIN_TURN_DEG:
        # the disturbance follows the pose: trials that barely turn the tool cannot show the
        # paper's figure, which is over its poses (the rotation trials turn up to 90 deg)
        r.status, r.note = "info", r.note + f"; the trials turn the tool at most {turn:.1f} deg"
    return r


MAG_MIN_TURN_DEG = 20.0


def _largest_trial_turn_deg(s: Session) -> float:
    """Largest rotation of the tool between a trial's pre and post windows [deg]."""
    rate, out = s.motion_rate_hz, 0.0
    for tr in s.trials:
        if "pre_start" not in tr or "post_end" not in tr:
            continue
        ta = np.array([(tr["pre_start"] + tr["pre_end"]) / 2 / rate * 1e9])
        tb = np.array([(tr["post_start"] + tr["post_end"]) / 2 / rate * 1e9])
        Ra, Rb = truth_R(s, ta)[0], truth_R(s, tb)[0]
        out = max(out, float(np.degrees(np.linalg.norm(so3_log(Ra.T @ Rb)))))
    return out


def report(path: str | Path) -> dict[str, Any]:
    s = load(path)
    wins = rest_windows(s)
    rows = (
        accel_rows(s, wins)
        + tof_rows(s, wins)
        + latency_rows(s)
        + [gyro_drift_row(s)]
        + vision_rows(s, wins)
        + motion_rows(s)
        + [mag_row(s)]
    )
    sess = s.meta.get("session", {})
    return {
        "file": str(path),
        "session": sess,
        "profile": profile_of(s),
        "rest_windows": len(wins),
        "rows": [asdict(r) for r in rows],
    }


def profile_of(s: Session) -> str:
    """The session's error profile: its session record, else its resolved scenario (sessions
    from before profiles carry neither: their models are the clean profile's)."""
    sess = s.meta.get("session", {})
    if "profile" in sess:
        return str(sess["profile"])
    return str((yaml.safe_load(s.meta.get("scenario", {}).get("yaml", "")) or {}).get("profile", "clean"))


def format_table(rep: dict[str, Any]) -> str:
    sess = rep["session"]
    head = (
        f"{rep['file']}: scenario {sess.get('scenario')} profile {rep.get('profile', '-')} protocol "
        f"{sess.get('protocol')} seed {sess.get('seed')} tier {sess.get('tier')}, {sess.get('duration_s')} s, "
        f"{rep['rest_windows']} rest windows"
    )
    lines = [head, f"{'statistic':<46} {'unit':<5} {'paper':<26} {'session':>9}  result  note"]
    for r in rep["rows"]:
        val = "-" if r["value"] is None else f"{r['value']:.3f}"
        lines.append(f"{r['name']:<46} {r['unit']:<5} {r['paper']:<26} {val:>9}  {r['status']:<6}  {r['note']}")
    n = [r["status"] for r in rep["rows"]]
    lines.append(f"{n.count('PASS')} PASS, {n.count('FAIL')} FAIL, {n.count('info')} info, {n.count('n/a')} n/a")
    return "\n".join(lines)
