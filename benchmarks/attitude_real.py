"""`tiplog fusion attitude` beside VQF (6-D) on real recordings: the BROAD tuning trials.

BROAD (Laidig et al., Data 2021) records a real IMU moved by hand with optical motion-capture
truth. For each trial in `--data` (default: shared/data/broad-tuning beside the repository),
the IMU's gyroscope and accelerometer are written to the command's CSV format and run through
`tiplog fusion attitude` (online) and `tiplog fusion attitude --smooth` (offline); VQF's
causal 6-D filter (`VQF.updateBatch`) and its offline variant (`offlineVQF`) run on the same
samples at their default parameters. Both take a gyroscope sample for the mean rate over the
step that ends at its stamp, so by default the two are aligned alike in time; `--gyr-delay-ms`
tells tiplog alone that the gyroscope lags its stamps (the BROAD IMU's lags the cameras by
about half a sample more, 1.75 ms: a shift that VQF is not given, so not the default). The
figure is the dataset's own six-axis metric: the
inclination part of q_est * conj(q_opt) (earth frame), RMS over the samples marked as
movement with an optical orientation, in degrees.

    python -m benchmarks.attitude_real [--data DIR] [--gyr-delay-ms MS] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA_DIR = ROOT.parent / "shared" / "data" / "broad-tuning"
METHODS = ("tiplog", "tiplog_smooth", "vqf", "vqf_offline")
GYR_DELAY_MS = 0.0


def load_trial(path: Path) -> dict[str, np.ndarray]:
    """One BROAD .mat file -> t_s (N,), gyr (N, 3) rad/s, acc (N, 3) m/s^2, q_opt (N, 4) w x y z
    sensor to ENU (NaN where the cameras lost it), movement (N,) bool, rate_hz."""
    from scipy.io import loadmat

    d = loadmat(path)
    rate_hz = float(np.asarray(d["sampling_rate"]).ravel()[0])
    gyr = np.ascontiguousarray(d["imu_gyr"], dtype=float)
    return {
        "t_s": np.arange(gyr.shape[0]) / rate_hz,
        "gyr": gyr,
        "acc": np.ascontiguousarray(d["imu_acc"], dtype=float),
        "q_opt": np.asarray(d["opt_quat"], dtype=float),
        "movement": np.asarray(d["movement"]).ravel() != 0,
        "rate_hz": rate_hz,
    }


def trials(data_dir: Path) -> list[Path]:
    return sorted(data_dir.glob("*.mat"))


def inclination_error_deg(q_est: np.ndarray, q_opt: np.ndarray) -> np.ndarray:
    """The dataset's heading-free error [deg] of each row: 2 arccos(sqrt(w^2 + z^2)) of
    q_e = q_est * conj(q_opt), both (N, 4) w x y z sensor to earth (z up); NaN where q_opt is."""
    w1, x1, y1, z1 = q_est.T
    w2, x2, y2, z2 = (q_opt * np.array([1.0, -1.0, -1.0, -1.0])).T
    w = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    z = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    n = np.sqrt((q_est**2).sum(1) * (q_opt**2).sum(1))
    c = np.clip(np.sqrt(w * w + z * z) / n, -1.0, 1.0)
    return np.degrees(2.0 * np.arccos(c))


def rms_deg(q_est: np.ndarray, trial: dict[str, np.ndarray]) -> float:
    """RMS of the inclination error over the movement samples that have an optical orientation."""
    err = inclination_error_deg(q_est, trial["q_opt"])
    keep = trial["movement"] & np.isfinite(err)
    return float(np.sqrt(np.mean(err[keep] ** 2)))


def write_csv(path: Path, trial: dict[str, np.ndarray]) -> None:
    """The trial's IMU samples in `tiplog fusion attitude`'s input format."""
    data = np.column_stack([trial["t_s"], trial["gyr"], trial["acc"]])
    np.savetxt(
        path,
        data,
        delimiter=",",
        fmt=["%.9f"] + ["%.9g"] * 6,
        header="t_s,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z",
        comments="",
    )


def run_tiplog(in_csv: Path, out_csv: Path, smooth: bool, gyr_delay_ms: float) -> tuple[np.ndarray, float]:
    """The command itself on the CSV; (N, 4) quaternions and its wall time [s]."""
    from tiplog.cli import main as tiplog_main

    args = ["fusion", "attitude", str(in_csv), str(out_csv), "--force", "--gyr-delay-ms", str(gyr_delay_ms)]
    args += ["--smooth"] if smooth else []
    t0 = time.perf_counter()
    if tiplog_main(args) != 0:
        raise RuntimeError(f"tiplog fusion attitude failed on {in_csv}")
    wall = time.perf_counter() - t0
    return np.loadtxt(out_csv, delimiter=",", skiprows=1)[:, 1:], wall


def run_vqf(trial: dict[str, np.ndarray], offline: bool) -> tuple[np.ndarray, float]:
    from vqf import VQF, offlineVQF  # benchmark-only reference

    ts = 1.0 / trial["rate_hz"]
    t0 = time.perf_counter()
    if offline:
        q = offlineVQF(trial["gyr"], trial["acc"], None, ts)["quat6D"]
    else:
        q = VQF(ts).updateBatch(trial["gyr"], trial["acc"])["quat6D"]
    return np.asarray(q), time.perf_counter() - t0


def one(path: Path, work: Path, gyr_delay_ms: float = GYR_DELAY_MS) -> dict:
    trial = load_trial(path)
    in_csv = work / f"{path.stem}.csv"
    write_csv(in_csv, trial)
    row: dict = {"trial": path.stem, "rows": int(trial["t_s"].shape[0]), "gyr_delay_ms": gyr_delay_ms, "wall_s": {}}
    for name in METHODS:
        if name.startswith("tiplog"):
            out_csv = work / f"{path.stem}_{name}.csv"
            q, wall = run_tiplog(in_csv, out_csv, name.endswith("smooth"), gyr_delay_ms)
        else:
            q, wall = run_vqf(trial, offline=name.endswith("offline"))
        row[name] = rms_deg(q, trial)
        row["wall_s"][name] = wall
    return row


def table(rows: list[dict]) -> str:
    head = f"{'trial':38} | {'tiplog':>7} {'VQF':>7} | {'tiplog':>7} {'VQF':>7}"
    lines = [f"{'':38} | {'online':^15} | {'offline':^15}", head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r['trial']:38} | {r['tiplog']:7.3f} {r['vqf']:7.3f} | {r['tiplog_smooth']:7.3f} {r['vqf_offline']:7.3f}"
        )
    m = {k: float(np.mean([r[k] for r in rows])) for k in METHODS}
    lines.append("-" * len(head))
    lines.append(
        f"{'mean':38} | {m['tiplog']:7.3f} {m['vqf']:7.3f} | {m['tiplog_smooth']:7.3f} {m['vqf_offline']:7.3f}"
    )
    lines.append("inclination error [deg], RMS over the movement samples with an optical orientation")
    lines.append(f"tiplog's gyroscope delay: {rows[0]['gyr_delay_ms']:g} ms" if rows else "")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.attitude_real", description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(DATA_DIR), help="folder of BROAD .mat trials")
    ap.add_argument(
        "--gyr-delay-ms", type=float, default=GYR_DELAY_MS, help="tiplog's gyroscope delay [ms] (default %(default)s)"
    )
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args(argv)
    files = trials(Path(args.data))
    if not files:
        print(f"attitude_real: no .mat trials in {args.data}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        rows = [one(f, Path(tmp), args.gyr_delay_ms) for f in files]
    print(table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
