"""`tiplog fusion attitude IN.csv OUT.csv`: a real CSV in, a real CSV out; a bad CSV gets one
line naming what is wrong and exit status 2, and an existing output is kept without --force."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tiplog.cli import main

HEADER = "t_s,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n"


def _rows(n: int = 400, rate_hz: float = 100.0) -> list[str]:
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        g = rng.normal(0, 0.01, 3)
        a = np.array([0.0, 9.81 * np.sin(0.3), 9.81 * np.cos(0.3)]) + rng.normal(0, 0.05, 3)  # tilted 0.3 rad about x
        out.append(",".join(f"{v:.6f}" for v in (1000.0 + i / rate_hz, *g, *a)) + "\n")
    return out


def _run(args: list[str], capsys) -> tuple[int, str]:
    rc = main(["fusion", "attitude", *map(str, args)])
    err = capsys.readouterr().err.strip()
    return rc, err


def test_roundtrip(tmp_path: Path, capsys):
    src, dst = tmp_path / "in.csv", tmp_path / "out.csv"
    # columns in another order, an extra column and a comment line are fine
    lines = ["# recorded by hand\n", "acc_x,acc_y,acc_z,t_s,temp_c,gyr_x,gyr_y,gyr_z\n"]
    for r in _rows():
        v = r.strip().split(",")
        lines.append(",".join([*v[4:7], v[0], "21.5", *v[1:4]]) + "\n")
    src.write_text("".join(lines))
    rc, err = _run([src, dst], capsys)
    assert rc == 0, err
    out = np.loadtxt(dst, delimiter=",", skiprows=1)
    assert dst.read_text().splitlines()[0] == "t_s,qw,qx,qy,qz"
    assert out.shape == (400, 5)
    np.testing.assert_allclose(out[:, 0], 1000.0 + np.arange(400) / 100.0)
    np.testing.assert_allclose(np.linalg.norm(out[:, 1:], axis=1), 1.0, atol=1e-6)
    # the sensor is tilted 0.3 rad: the estimate's up direction in sensor axes says so
    w, x, y, z = out[-1, 1:]
    up_sensor = np.array([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])
    assert np.degrees(np.arccos(up_sensor @ [0.0, np.sin(0.3), np.cos(0.3)])) < 1.0


@pytest.mark.parametrize(
    "text,needle",
    [
        ("".join(_rows(5)), "header lacks column(s) t_s"),
        ("t_s,gyr_x,gyr_y,gyr_z,acc_x,acc_y\n" + "1,0,0,0,0,0\n" * 3, "lacks column(s) acc_z"),
        (HEADER + "".join(_rows(3)) + "1000.04,0,0,zero,0,0,9.8\n", "line 5, column gyr_z: 'zero' is not a number"),
        (HEADER + "".join(_rows(3)[::-1]), "line 3, column t_s: time goes backwards (1000.01 s after 1000.02 s)"),
        (
            HEADER + "".join(_rows(3)) + "1000.04,1e300,0,0,0,0,9.8\n",
            "line 5, column gyr_x: 1e+300 is beyond +-1000 rad/s",
        ),
        (HEADER + "".join(_rows(3)) + "1000.04,0,-inf,0,0,0,9.8\n", "line 5, column gyr_y: -inf is beyond"),
        (
            HEADER + "".join(_rows(3)) + "1000.04,0,0,0,0,0,1e9\n",
            "line 5, column acc_z: 1000000000.0 is beyond +-5000 m/s^2",
        ),
        (HEADER + "".join(_rows(2)) + ",0,0,0,0,0,9.8\n", "line 4, column t_s: time missing"),
        (HEADER + "".join(_rows(2)) + "1000.05,0,0\n", "line 4: 3 fields"),
        (HEADER + "1000,0,0,0,,,\n1001,0,0,0,,,\n", "no row has a complete accelerometer sample"),
        (HEADER + "".join(_rows(1)), "at least two data rows"),
        ("\x00\x01\x02\xff\xfe", "not a text CSV file"),
    ],
)
def test_bad_csv_one_line_exit_2(tmp_path: Path, capsys, text: str, needle: str):
    src, dst = tmp_path / "in.csv", tmp_path / "out.csv"
    src.write_bytes(text.encode("latin-1"))
    rc, err = _run([src, dst], capsys)
    assert rc == 2
    assert len(err.splitlines()) == 1 and needle in err, err
    assert not dst.exists()


def test_missing_input_and_existing_output(tmp_path: Path, capsys):
    rc, err = _run([tmp_path / "nope.csv", tmp_path / "out.csv"], capsys)
    assert rc == 2 and "no such CSV file" in err
    src, dst = tmp_path / "in.csv", tmp_path / "out.csv"
    src.write_text(HEADER + "".join(_rows(50)))
    dst.write_text("keep me\n")
    rc, err = _run([src, dst], capsys)
    assert rc == 2 and "--force" in err and len(err.splitlines()) == 1
    assert dst.read_text() == "keep me\n"
    rc, err = _run([src, dst, "--force"], capsys)
    assert rc == 0 and dst.read_text().startswith("t_s,qw")


def test_bad_parameter_exit_2(tmp_path: Path, capsys):
    src = tmp_path / "in.csv"
    src.write_text(HEADER + "".join(_rows(50)))
    rc, err = _run([src, tmp_path / "out.csv", "--tau-acc", "0"], capsys)
    assert rc == 2 and "tau_acc_s" in err
    rc, err = _run([src, tmp_path / "out.csv", "--gyr-delay-ms", "-1"], capsys)
    assert rc == 2 and "gyr_delay_s: must be from 0 to 0.1 s" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out.csv").exists()


def test_accelerometer_norm_far_from_g_is_refused(tmp_path: Path, capsys):
    src, dst = tmp_path / "in.csv", tmp_path / "out.csv"
    rows = []
    for r in _rows():
        v = [float(x) for x in r.split(",")]
        rows.append(",".join(f"{x:.9f}" for x in [*v[:4], *(np.array(v[4:]) * 0.3)]) + "\n")  # 2.9 m/s^2
    src.write_text(HEADER + "".join(rows))
    rc, err = _run([src, dst], capsys)
    assert rc == 2 and len(err.splitlines()) == 1
    assert "median norm is 2.94, neither about 9.81 m/s^2 nor about 1 g" in err, err
    assert not dst.exists()


def test_accelerometer_in_g_is_scaled_with_a_note(tmp_path: Path, capsys):
    src, dst, ref = tmp_path / "in.csv", tmp_path / "out.csv", tmp_path / "ref.csv"
    rows = _rows()
    src.write_text(HEADER + "".join(rows))
    assert _run([src, ref], capsys) == (0, "")
    g_rows = []
    for r in rows:
        v = [float(x) for x in r.split(",")]
        g_rows.append(",".join(f"{x:.9f}" for x in [*v[:4], *(np.array(v[4:]) / 9.81)]) + "\n")
    src.write_text(HEADER + "".join(g_rows))
    rc, err = _run([src, dst], capsys)
    assert rc == 0 and "not near 9.81" in err
    np.testing.assert_allclose(
        np.loadtxt(dst, delimiter=",", skiprows=1), np.loadtxt(ref, delimiter=",", skiprows=1), atol=1e-5
    )
