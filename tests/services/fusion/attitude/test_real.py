"""`tiplog fusion attitude` on a real recording: 30 s of a BROAD trial (a real IMU turned fast
by hand, optical truth), written to the command's CSV at the IMU's own 285.7 Hz. The command
stays accurate there, also across a gap and a row of NaN; a wrong column order gets one line
and exit status 2. The data sits in shared/data/broad-tuning beside the repository
(TIPLOG_BROAD_DIR points elsewhere); without it these tests skip."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from benchmarks.attitude_real import DATA_DIR, inclination_error_deg, load_trial, write_csv
from tiplog.cli import main

BROAD = Path(os.environ.get("TIPLOG_BROAD_DIR", DATA_DIR))
TRIAL = BROAD / "06_undisturbed_fast_rotation_A.mat"
pytestmark = pytest.mark.skipif(
    not TRIAL.exists(), reason=f"BROAD tuning data not found at {TRIAL} (shared/data/broad-tuning beside the repo)"
)
DELAY = ["--gyr-delay-ms", "1.75"]  # the BROAD IMU's gyroscope lags the cameras by about half a sample


@pytest.fixture(scope="module")
def piece() -> dict:
    """30 s from 30 s in: 7 s of rest, then fast rotation by hand."""
    tr = load_trial(TRIAL)
    sel = (tr["t_s"] >= 30.0) & (tr["t_s"] < 60.0)
    return {k: (v[sel] if isinstance(v, np.ndarray) else v) for k, v in tr.items()}


def _attitude(tmp_path: Path, piece: dict, *opts: str, name: str = "in.csv") -> tuple[int, np.ndarray | None]:
    src, dst = tmp_path / name, tmp_path / f"out_{name}"
    if not src.exists():
        write_csv(src, piece)
    rc = main(["fusion", "attitude", str(src), str(dst), "--force", *opts])
    out = np.loadtxt(dst, delimiter=",", skiprows=1) if rc == 0 else None
    return rc, out


def _rms(q: np.ndarray, piece: dict, sel: np.ndarray | None = None) -> float:
    err = inclination_error_deg(q, piece["q_opt"])
    keep = piece["movement"] & np.isfinite(err) & (True if sel is None else sel)
    return float(np.sqrt(np.mean(err[keep] ** 2)))


def test_real_rate_online_and_offline(tmp_path: Path, piece: dict, capsys):
    assert abs(piece["rate_hz"] - 285.714) < 0.01
    rc, plain = _attitude(tmp_path, piece)
    assert rc == 0, capsys.readouterr().err
    rc, delayed = _attitude(tmp_path, piece, *DELAY)
    rc2, smoothed = _attitude(tmp_path, piece, *DELAY, "--smooth")
    assert rc == rc2 == 0
    assert capsys.readouterr().err == ""
    assert plain.shape == (piece["t_s"].size, 5)
    np.testing.assert_allclose(plain[:, 0], piece["t_s"], atol=1e-9)
    on, off = _rms(delayed[:, 1:], piece), _rms(smoothed[:, 1:], piece)
    # fast turns by hand: within a degree of the cameras, with or without the delay option, and
    # the delay undone better than not
    assert on < 1.0 and off < 1.0 and _rms(plain[:, 1:], piece) < 1.0
    assert on < _rms(plain[:, 1:], piece)


def test_gap_and_nan_row(tmp_path: Path, piece: dict, capsys):
    t = piece["t_s"]
    keep = (t < 45.0) | (t >= 47.0)  # two seconds lost in the middle of the turning
    cut = {k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in piece.items()}
    cut["gyr"], cut["acc"] = cut["gyr"].copy(), cut["acc"].copy()
    row = int(np.searchsorted(cut["t_s"], 50.0))
    cut["gyr"][row] = np.nan  # one row with neither sensor
    cut["acc"][row] = np.nan
    for opts in ([], ["--smooth"]):
        rc, out = _attitude(tmp_path, cut, *DELAY, *opts, name="cut.csv")
        assert rc == 0, capsys.readouterr().err
        assert out.shape == (cut["t_s"].size, 5) and np.isfinite(out).all()
        # before the gap as before; after it the inclination is back from gravity within seconds
        assert _rms(out[:, 1:], cut, cut["t_s"] < 45.0) < 1.0
        assert _rms(out[:, 1:], cut, cut["t_s"] > 52.0) < 1.5
    assert "nan" in (tmp_path / "cut.csv").read_text().splitlines()[row + 1].lower()


@pytest.mark.parametrize(
    "header,needle",
    [
        ("t_s,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z", "acc_* columns"),  # the two sensors swapped
        ("t_s,gyr_x,gyr_y,gyr_z,acc_y,acc_x,acc_z", "axes disagree"),  # two accelerometer axes
        ("t_s,gyr_y,gyr_x,gyr_z,acc_x,acc_y,acc_z", "axes disagree"),  # two gyroscope axes
        ("t_s,gyr_x,gyr_y,gyr_z,acc_x,acc_z,acc_y", "axes disagree"),
    ],
)
def test_wrong_column_order_one_line_exit_2(tmp_path: Path, piece: dict, capsys, header: str, needle: str):
    src, dst = tmp_path / "in.csv", tmp_path / "out.csv"
    write_csv(src, piece)
    lines = src.read_text().splitlines(keepends=True)
    src.write_text(header + "\n" + "".join(lines[1:]))
    rc = main(["fusion", "attitude", str(src), str(dst)])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and needle in err and "Traceback" not in err, err
    assert not dst.exists()


@pytest.mark.slow
def test_benchmarks_run_on_a_short_trial(tmp_path: Path, capsys):
    """Both real-data benchmarks on 40 s of the trial (20 s each side of the movement's start
    and of its end) written back as a BROAD .mat file."""
    from scipy.io import loadmat, savemat

    from benchmarks import attitude_real, imu_real

    d = loadmat(TRIAL)
    t = np.arange(d["imu_gyr"].shape[0]) / float(d["sampling_rate"][0, 0])
    keep = ((t >= 25.0) & (t < 45.0)) | ((t >= 150.0) & (t < 170.0))
    short = {k: (v[keep] if isinstance(v, np.ndarray) and v.shape[:1] == t.shape else v) for k, v in d.items()}
    savemat(tmp_path / TRIAL.name, {k: v for k, v in short.items() if not k.startswith("__")})
    out = tmp_path / "att.json"
    assert attitude_real.main(["--data", str(tmp_path), "--json", str(out)]) == 0
    (row,) = json.loads(out.read_text())
    for name in attitude_real.METHODS:
        assert 0.0 < row[name] < 3.0, (name, row[name])  # a wrong frame or sign gives tens of degrees
    printed = capsys.readouterr().out
    assert TRIAL.stem in printed and "mean" in printed
    assert imu_real.main(["--data", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "deg/s/rtHz" in printed and "rest called" in printed
