"""`tiplog fusion attitude IN.csv OUT.csv`: the IMU's orientation alone (sensor to an earth
frame with z up, heading arbitrary), from gyroscope and accelerometer samples.

IN.csv has a header row naming at least the columns t_s, gyr_x, gyr_y, gyr_z [rad/s],
acc_x, acc_y, acc_z [m/s^2], in any order (other columns are ignored; lines starting with '#'
are comments). Time must not decrease; any rate, jitter and dropped rows are fine. An empty or
NaN gyroscope or accelerometer value marks that sensor missing in its row; an infinite one, or
one beyond +-1000 rad/s or +-5000 m/s^2, is refused with its line and column. So is an
accelerometer whose median norm is neither about 9.81 m/s^2 nor about 1 g, and one whose axes
disagree with the gyroscope's (gravity, carried through the gyroscope's turns, does not stay
put: columns swapped or mislabelled). OUT.csv gets t_s, qw, qx, qy, qz for every input row.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

import numpy as np

from tiplog.userio import UserError, atomic_output, input_file, output_file

COLUMNS = ("t_s", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z")
# Beyond any MEMS sensor's range (gyroscopes reach about 70 rad/s = 4000 deg/s, accelerometers
# about 200 g): a value past these is a unit or transcription error, and 1e300 overflowed the
# filter into a traceback.
MAX_GYR_RADPS = 1000.0
MAX_ACC_MPS2 = 5000.0
_MISSING = {"", "nan", "NaN", "NAN", "-nan", "na", "NA", "null"}
# Axis check: 5 s windows in which the gyroscope turns the sensor by more than 30 deg. With
# consistent axes gravity, rotated through the gyroscope's turns into a fixed frame, averages
# to about g there (motion accelerations average out); with swapped or mislabelled columns it
# smears over the turn and its mean falls short of g by tens of percent.
AXES_WINDOW_S = 5.0
AXES_MIN_TURN_DEG = 30.0
AXES_MIN_WINDOWS = 3
AXES_MAX_LOSS = 0.15


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="CSV: t_s, gyr_x, gyr_y, gyr_z [rad/s], acc_x, acc_y, acc_z [m/s^2]")
    p.add_argument("output", help="CSV to write: t_s, qw, qx, qy, qz")
    p.add_argument("--force", action="store_true", help="overwrite OUTPUT if it exists")
    p.add_argument("--tau-acc", type=float, default=None, metavar="S", help="accelerometer time constant (default 3 s)")
    p.add_argument("--no-bias", action="store_true", help="do not estimate the gyroscope bias")
    p.add_argument(
        "--gyr-delay-ms",
        type=float,
        default=None,
        metavar="MS",
        help="the gyroscope's samples lag their stamps and the accelerometer by this (default 0)",
    )
    p.add_argument(
        "--smooth",
        action="store_true",
        help="offline: each row's orientation from the rows before and after it (not causal)",
    )
    p.set_defaults(func=run)


def read_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_s (N,), gyr (N, 3) rad/s, acc (N, 3) m/s^2; NaN where missing), or UserError naming
    the line and column that is wrong."""
    p = input_file(path, "CSV file")
    try:
        with open(p, newline="", encoding="utf-8-sig") as f:
            lines = [(i + 1, ln) for i, ln in enumerate(f) if ln.strip() and not ln.lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise UserError(f"{p}: not a text CSV file") from None
    except OSError as e:
        raise UserError(f"{p}: cannot read ({e.strerror or e})") from None
    if not lines:
        raise UserError(f"{p}: no header row (expected columns {', '.join(COLUMNS)})")
    rows = list(csv.reader(ln for _, ln in lines))
    header = [h.strip().lower() for h in rows[0]]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise UserError(
            f"{p}: line {lines[0][0]}: header lacks column(s) {', '.join(missing)} "
            f"(expected a header row naming {', '.join(COLUMNS)})"
        )
    idx = [header.index(c) for c in COLUMNS]
    if len(rows) < 3:
        raise UserError(f"{p}: needs at least two data rows (found {len(rows) - 1})")
    data = np.empty((len(rows) - 1, len(COLUMNS)))
    for r, (row, (line, _)) in enumerate(zip(rows[1:], lines[1:], strict=True)):
        if len(row) < len(header):
            raise UserError(f"{p}: line {line}: {len(row)} fields, the header has {len(header)}")
        for c, j in enumerate(idx):
            cell = row[j].strip()
            if cell in _MISSING:
                data[r, c] = math.nan
                continue
            try:
                data[r, c] = float(cell)
            except ValueError:
                raise UserError(f"{p}: line {line}, column {COLUMNS[c]}: {cell[:40]!r} is not a number") from None
    t = data[:, 0]
    bad = ~np.isfinite(t)
    if bad.any():
        k = int(np.argmax(bad))
        raise UserError(f"{p}: line {lines[k + 1][0]}, column t_s: time missing or not finite")
    back = np.diff(t) < 0
    if back.any():
        k = int(np.argmax(back)) + 1
        raise UserError(
            f"{p}: line {lines[k + 1][0]}, column t_s: time goes backwards "
            f"({float(t[k])!r} s after {float(t[k - 1])!r} s)"
        )
    for cols, limit, what in ((slice(1, 4), MAX_GYR_RADPS, "rad/s"), (slice(4, 7), MAX_ACC_MPS2, "m/s^2")):
        block = data[:, cols]
        bad = np.isinf(block) | (np.abs(np.nan_to_num(block)) > limit)
        if bad.any():
            r, c = (int(x) for x in np.argwhere(bad)[0])
            col = COLUMNS[cols.start + c]
            raise UserError(
                f"{p}: line {lines[r + 1][0]}, column {col}: {float(block[r, c])!r} is beyond +-{limit:g} {what} "
                f"(a sensor's range is far less; is the column in {what}?)"
            )
    if not np.isfinite(data[:, 4:7]).all(axis=1).any():
        raise UserError(f"{p}: no row has a complete accelerometer sample (acc_x, acc_y, acc_z)")
    if not np.isfinite(data[:, 1:4]).all(axis=1).any():
        raise UserError(f"{p}: no row has a complete gyroscope sample (gyr_x, gyr_y, gyr_z)")
    return t, data[:, 1:4], data[:, 4:7]


def check_axes(t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray, max_gap_s: float) -> str | None:
    """None when the gyroscope's and accelerometer's axes agree (or too little turning to
    tell); else what is wrong, in words. Inputs as `read_csv` returns them, acc in m/s^2."""
    from services.fusion.attitude.offline import strapdown

    g_ok = np.isfinite(gyr).all(axis=1)
    a_ok = np.isfinite(acc).all(axis=1)
    gyr = np.column_stack([np.interp(t_s, t_s[g_ok], gyr[g_ok, k]) for k in range(3)])
    q, acc_fixed = strapdown(t_s, gyr, acc)
    g_ref = float(np.median(np.linalg.norm(acc[a_ok], axis=1)))
    edges = np.searchsorted(t_s, np.arange(t_s[0], t_s[-1], AXES_WINDOW_S))
    loss = []
    for i0, i1 in zip(edges[:-1], edges[1:], strict=True):
        if i1 - i0 < 10 or np.any(np.diff(t_s[i0:i1]) > max_gap_s) or a_ok[i0:i1].sum() < 10:
            continue
        q_mid = q[(i0 + i1) // 2]
        turn_deg = np.degrees(2.0 * np.arccos(np.clip(np.abs(q[i0:i1] @ q_mid), 0.0, 1.0))).max()
        if turn_deg > AXES_MIN_TURN_DEG:
            mean = acc_fixed[i0:i1][a_ok[i0:i1]].mean(axis=0)
            loss.append(abs(1.0 - float(np.linalg.norm(mean)) / g_ref))
    if len(loss) < AXES_MIN_WINDOWS or np.median(loss) <= AXES_MAX_LOSS:
        return None
    return (
        f"the accelerometer's axes disagree with the gyroscope's: over {len(loss)} windows of "
        f"{AXES_WINDOW_S:g} s in which the gyroscope turns more than {AXES_MIN_TURN_DEG:g} deg, gravity "
        f"carried through its turns stays {100 * float(np.median(loss)):.0f} % off its length (median; "
        f"consistent axes stay within a few %): are the gyr_* and acc_* columns in the right order?"
    )


def write_csv(path: Path, t_s: np.ndarray, q_wxyz: np.ndarray) -> None:
    """t_s, qw, qx, qy, qz, one row per sample."""
    with open(path, "w", newline="") as f:
        f.write("t_s,qw,qx,qy,qz\n")
        for t, q in zip(t_s, q_wxyz, strict=True):
            f.write(f"{float(t)!r},{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f}\n")


def run(args: argparse.Namespace) -> int:
    from services.fusion.attitude.filter import Params, estimate
    from services.fusion.attitude.offline import smooth

    kw = {}
    if args.tau_acc is not None:
        kw["tau_acc_s"] = args.tau_acc
    if args.gyr_delay_ms is not None:
        kw["gyr_delay_s"] = args.gyr_delay_ms * 1e-3
    try:
        params = Params(estimate_bias=not args.no_bias, **kw)
    except ValueError as e:
        raise UserError(str(e)) from None
    # the input first, then OUTPUT, which must not be it: refused before the CSV is read
    input_file(args.input, "CSV file")
    output_file(args.output, args.force)
    t_s, gyr, acc = read_csv(args.input)
    norm = np.linalg.norm(acc, axis=1)
    g_med = float(np.nanmedian(norm[norm > 0])) if np.any(norm > 0) else 0.0
    if 0.5 <= g_med <= 1.5:
        # only the direction matters to the filter, but its rest threshold is in m/s^2
        print(
            f"tiplog fusion attitude: note: median |acc| is {g_med:.3g}, not near 9.81 m/s^2; "
            "scaling the accelerometer to 9.81 (units in g?)",
            file=sys.stderr,
        )
        acc = acc * (9.81 / g_med)
    elif not 5.0 <= g_med <= 15.0:
        raise UserError(
            f"{args.input}: the accelerometer's median norm is {g_med:.3g}, neither about 9.81 m/s^2 nor "
            "about 1 g: are the acc_* columns the accelerometer's, in m/s^2 or g?"
        )
    wrong = check_axes(t_s, gyr, acc, params.max_gap_s)
    if wrong:
        raise UserError(f"{args.input}: {wrong}")
    q = (smooth if args.smooth else estimate)(t_s, gyr, acc, params)
    with atomic_output(args.output, args.force) as tmp:
        write_csv(tmp, t_s, q)
    return 0
