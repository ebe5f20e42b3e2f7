"""What each vision blackout costs the tracking filter, and how much of it the gyroscope's walk explains.

Without vision the heading (the turn about the vertical through the RCM) is held by the gyro
alone, and weakly by the ToF, which sees it mixed with the depth (`benchmarks.tof_heading`).
The bench's gyro bias walks with the angular rate (bench facts: 89 deg accumulated over a
102 s roll sweep), so what a blackout costs depends on how far the bias walked while vision
was away. For every blackout of the `blackoutN` ablation (`study.ablation`; the
paper's sixteen shared over the sessions given, or sixteen per session) this runs the filter
(vision blanked, everything else as recorded) and, against the bench's truth (here, in the
benchmark, never in an estimator), reports:

- the tip error (RMS over the blackout, and at its end), the heading error at its start and
  end, and the depth error along the shaft at its end;
- the filter's gyro bias error at the blackout's start, and the heading drift that bias alone
  would give over the blackout with the true bias as it walked: the integral of the vertical
  component (in the base frame) of true minus estimated-at-start bias. Where that drift is
  close to the heading the filter lost over the blackout, the gyro's walk set the cost; the
  correlation and slope of the two over all blackouts are printed;
- the filter's own heading sigma at the blackout's start and end (its covariance, read as it
  runs), and the heading lost in units of that sigma's growth: an RMS over the blackouts near 1
  says the filter's heading uncertainty through a blackout is honest, a larger one that it
  is overconfident.

The true bias is the gyro's reading less the robot's rate in IMU axes (the session's
`calibration_truth` mounting and latency), averaged over `--bias-window` seconds: the gyro's
whole error, so its scale error (0.2 %, a bias that moves with the rate) is in it too, as it is
in what the filter integrates.

    python -m benchmarks.blackout_anatomy SWEEPS.mcap [TELEOP.mcap ...] [--calibration FILE]
        [--length 10] [--count 16] [--per-session] [--sensors imu,tof,vision] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from services.bench.report.data import load, truth_p, truth_R
from services.fusion.eskf.params import Params
from services.fusion.offline.inputs import iter_inputs
from services.fusion.params_file import load_params
from study.ablation import BLACKOUT_COUNT, blackout_spans, degrade, run_states, sessions_blackouts
from study.evaluation import EvaluationError, block_windows
from tiplog.calibration import Calibration, CalibrationError
from tiplog.calibration.block import robot_body_rate
from tiplog.geometry import quat_to_rot, so3_log
from tiplog.mcap_io import read_metadata
from tiplog.userio import UserError

LENGTHS_S = (1, 3, 10)


def true_gyro_bias(s, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(times [ns], bias (n, 3) [rad/s], IMU axes): the gyro's reading less the robot's rate,
    averaged over consecutive windows of `window_s` (the white noise averages out, the walk
    does not)."""
    g = s.streams["gyro"]
    t = g["t"] - int(round(s.truth.latency_ms.get("gyro", 0.0) * 1e6))  # event time
    keep = (t > s.robot_t[0]) & (t < s.robot_t[-1])
    t, w_meas = t[keep], g["v"][keep]
    tm, w_tool = robot_body_rate(s.robot_t, s.robot_R)
    w_imu = np.stack([np.interp(t, tm, w_tool[:, j]) for j in range(3)], 1) @ s.truth.R_tool_imu
    b = w_meas - w_imu
    edges = np.arange(t[0], t[-1], int(window_s * 1e9))
    idx = np.searchsorted(edges, t, side="right") - 1
    n = np.bincount(idx, minlength=len(edges)).astype(float)
    ok = n > 0
    mean = np.stack([np.bincount(idx, b[:, j], minlength=len(edges)) for j in range(3)], 1)[ok] / n[ok, None]
    centres = (edges + int(window_s * 0.5e9))[ok]
    return centres, mean


def _interp_rows(t: np.ndarray, tp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t, tp, fp[:, j]) for j in range(fp.shape[1])], 1)


def analyse(
    session: Path,
    calib: Calibration | None,
    params: Params,
    length_s: float,
    count: int,
    bias_window_s: float,
    sensors: str = "imu,tof,vision",
) -> list[dict]:
    md = read_metadata(session)
    if "calibration_truth" not in md:
        raise EvaluationError(f"{session}: not a bench session (no calibration_truth)")
    s = load(session)
    if len(s.streams["gyro"]["t"]) < 10:
        raise EvaluationError(f"{session}: no gyro samples")
    if calib is None:
        calib = Calibration.from_mcap_metadata(md, where=str(session))
    blocks = block_windows(s.trials)
    if not blocks:
        raise EvaluationError(f"{session}: no continuous blocks (sweeps, teleop, demo)")
    spans = blackout_spans(blocks, int(length_s * 1e9), count)
    name = f"blackout{length_s:g}"
    sigma = _HeadingSigma()
    msgs = degrade(name, iter_inputs(session, {}), blocks, blackouts=count)
    states, _ = run_states(msgs, calib, params, sensors, probe=sigma)
    if not states:
        raise EvaluationError(f"{session}: the filter published no state")
    t_est = np.array([x.stamp_ns for x in states], np.int64)
    tip = np.array([x.p_tip_base_m for x in states])
    R_est = quat_to_rot(np.roll(np.array([x.q_base_tool for x in states]), -1, axis=1))  # w, x, y, z -> x, y, z, w
    bg = np.array([x.gyro_bias_radps for x in states])
    tb, b_true = true_gyro_bias(s, bias_window_s)
    R_ti = s.truth.R_tool_imu
    rcm = s.truth.rcm_base_m
    rows = []
    for a, e in spans:
        k = (t_est >= a) & (t_est < e) & (t_est >= s.robot_t[0]) & (t_est <= s.robot_t[-1])
        if k.sum() < 10:
            continue
        tk = t_est[k]
        err = np.linalg.norm(tip[k] - truth_p(s, tk), axis=1) * 1e3
        start, end = np.flatnonzero(k)[[0, -1]]
        R_est_end = R_est[end]
        heading_deg = [_heading_error_deg(R_est[i], truth_R(s, t_est[i : i + 1])[0]) for i in (start, end)]
        sigma_deg = [sigma.at(t_est[i]) for i in (start, end)]
        p_true = truth_p(s, tk[-1:])[0]
        depth_err_mm = float((np.dot(tip[end] - rcm, R_est_end[:, 2]) - np.linalg.norm(p_true - rcm)) * 1e3)
        # the bias held from the start against the walking truth, its vertical part in the base frame
        b_true_k = _interp_rows(tk, tb, b_true)
        R_k = truth_R(s, tk)
        vert = np.einsum("nij,jk,nk->ni", R_k, R_ti, b_true_k - bg[start])[:, 2]
        drift = float(np.degrees(np.sum(vert[:-1] * np.diff(tk) * 1e-9)))
        walk = np.degrees(np.linalg.norm(b_true_k[-1] - b_true_k[0]))
        block = next((n for n, lo, hi in blocks if lo <= a < hi), "")
        rows.append(
            {
                "session": session.name,
                "block": block,
                "start_s": round(a * 1e-9, 2),
                "length_s": length_s,
                "tip_rms_mm": float(np.sqrt(np.mean(err**2))),
                "tip_end_mm": float(err[-1]),
                "heading_start_deg": heading_deg[0],
                "heading_end_deg": heading_deg[1],
                "heading_change_deg": heading_deg[1] - heading_deg[0],
                "heading_sigma_start_deg": sigma_deg[0],
                "heading_sigma_end_deg": sigma_deg[1],
                "depth_end_mm": depth_err_mm,
                "bias_error_start_dps": float(np.degrees(np.linalg.norm(bg[start] - b_true_k[0]))),
                "bias_walk_dps": float(walk),
                "gyro_drift_deg": drift,
            }
        )
    return rows


class _HeadingSigma:
    """The filter's own heading 1-sigma [deg] (its attitude covariance about the base frame's
    vertical) read at its head after every advance, kept every `every_ns`: what the filter
    believes it may have lost, beside what it lost."""

    def __init__(self, every_ns: int = 20_000_000):
        self.every_ns = every_ns
        self.t: list[int] = []
        self.sd: list[float] = []

    def __call__(self, runner) -> None:
        s = runner.head
        if s is None or (self.t and s.t_ns - self.t[-1] < self.every_ns):
            return
        z = s.R[2]  # the base vertical in tool coordinates (R^T e_z): the local error's direction
        self.t.append(int(s.t_ns))
        self.sd.append(float(np.degrees(np.sqrt(max(z @ s.P[6:9, 6:9] @ z, 0.0)))))

    def at(self, t_ns: int) -> float:
        return float(np.interp(t_ns, self.t, self.sd)) if self.t else float("nan")


def heading_z(rows: list[dict]) -> np.ndarray:
    """Each blackout's heading change over the growth of the filter's heading sigma,
    sqrt(end^2 - start^2): an RMS near 1 says the sigma shown was honest, above 1 overconfident."""
    grow = np.array([max(r["heading_sigma_end_deg"] ** 2 - r["heading_sigma_start_deg"] ** 2, 1e-12) for r in rows])
    return np.array([r["heading_change_deg"] for r in rows]) / np.sqrt(grow)


def _heading_error_deg(R_est: np.ndarray, R_true: np.ndarray) -> float:
    """The estimate's turn from the truth about the base frame's vertical [deg]."""
    return float(np.degrees(so3_log(R_est @ R_true.T)[2]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.blackout_anatomy", description=__doc__.splitlines()[0])
    ap.add_argument("sessions", nargs="+", type=Path, help="bench sessions (MCAP) with continuous blocks")
    ap.add_argument("--calibration", type=Path, help="calibration YAML (default: each session's as-calibrated)")
    ap.add_argument("--params", type=Path, help="filter parameters YAML (default: the built-in ones)")
    ap.add_argument("--length", type=float, default=10.0, choices=LENGTHS_S, help="blackout length [s] (default 10)")
    ap.add_argument(
        "--per-session", action="store_true", help="--count blackouts in each session, not shared over them"
    )
    ap.add_argument(
        "--sensors",
        default="imu,tof,vision",
        help="the filter's sensors (default imu,tof,vision; imu,vision: the gyro alone)",
    )
    ap.add_argument(
        "--count", type=int, default=BLACKOUT_COUNT, help=f"blackouts (default {BLACKOUT_COUNT}, the paper's)"
    )
    ap.add_argument("--bias-window", type=float, default=1.0, help="true bias averaged over this long [s]")
    ap.add_argument("--json", type=Path, help="write the rows to this file")
    a = ap.parse_args(argv)
    rows = []
    try:
        calib = Calibration.load_yaml(a.calibration) if a.calibration else None
        params = load_params(a.params) if a.params else Params()
        if a.count < 1:
            raise ValueError(f"--count must be at least 1 (got {a.count})")
        counts = [a.count] * len(a.sessions) if a.per_session else sessions_blackouts(a.sessions, a.count)
        for s, n in zip(a.sessions, counts, strict=True):
            rows += analyse(s, calib, params, a.length, n, a.bias_window, a.sensors)
    except (OSError, UserError, EvaluationError, CalibrationError, KeyError, ValueError) as e:
        print(f"blackout_anatomy: {e}", file=sys.stderr)
        return 2
    print(
        "session / block @ start (s): tip RMS, end (mm) | heading error at start, end (deg; the filter's sigma) | "
        "depth at end (mm) | "
        "bias error at start, true walk (deg/s) | heading drift of the held bias (deg)"
    )
    for r in rows:
        print(
            f"{r['session']} / {r['block']} @ {r['start_s']:.1f}: {r['tip_rms_mm']:.2f}, {r['tip_end_mm']:.2f} | "
            f"{r['heading_start_deg']:+.2f} ({r['heading_sigma_start_deg']:.2f}), "
            f"{r['heading_end_deg']:+.2f} ({r['heading_sigma_end_deg']:.2f}) | {r['depth_end_mm']:+.2f} | "
            f"{r['bias_error_start_dps']:.3f}, {r['bias_walk_dps']:.3f} | {r['gyro_drift_deg']:+.2f}"
        )
    if len(rows) > 2:
        h = np.array([r["heading_change_deg"] for r in rows])
        d = np.array([r["gyro_drift_deg"] for r in rows])
        print(
            f"heading lost over a blackout vs the held bias's drift: correlation {np.corrcoef(h, d)[0, 1]:.2f}, "
            f"slope {np.polyfit(d, h, 1)[0]:.2f} over {len(rows)}"
        )
        z = heading_z(rows)
        print(
            f"heading lost over a blackout in units of the filter's own sigma growth: RMS {np.sqrt(np.mean(z**2)):.2f}, "
            f"largest {np.max(np.abs(z)):.1f} (1: the heading sigma is honest; above: overconfident)"
        )
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
