"""What the user has is never lost: no command's output replaces one of its own inputs (by any
spelling, `--force` or not), nor a device or pipe; an MCAP file damaged in the middle or at its
end is refused in one line saying where and that `tiplog record recover` salvages it, instead of
being read silently or ending in a traceback. Every case: exit status 2, one line on stderr, the
inputs byte-identical afterwards and no file left behind."""

from __future__ import annotations

import hashlib
import os
import stat
import subprocess
import sys

import cv2
import numpy as np
import pytest

from tests.conftest import ROOT, free_port
from tests.services.fusion.sessions import sweeps_estimate_fixture, sweeps_session_fixture  # noqa: F401 (fixtures session, estimate)
from tests.tiplog.calibration.test_hand_eye import _poses, _true_camera
from tests.tiplog.calibration.test_intrinsics import _views
from tiplog.calibration import Calibration
from tiplog.calibration.hand_eye import write_pose_csv
from tiplog.cli import main
from tiplog.mcap_io import read_metadata, read_summary


@pytest.fixture(scope="module")
def board_views():
    return _views(11, 8)


@pytest.fixture
def files(tmp_path, session, estimate, board_views):
    """A folder with a copy of every kind of input the commands read (the originals stay safe
    whatever a command does)."""
    d = tmp_path / "d"
    d.mkdir()
    (d / "in.mcap").write_bytes(session.read_bytes())
    (d / "est.mcap").write_bytes(estimate.read_bytes())
    Calibration.from_mcap_metadata(read_metadata(session)).save_yaml(d / "cal.yaml")
    rng = np.random.default_rng(0)
    rows = ["t_s,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"]
    rows += [",".join(f"{v:.6f}" for v in (i / 100, *rng.normal(0, 0.01, 3), 0.0, 0.0, 9.81)) for i in range(200)]
    (d / "imu.csv").write_text("\n".join(rows) + "\n")
    write_pose_csv(d / "poses.csv", *_poses(10, 30, _true_camera()))
    (d / "board").mkdir()
    for k, img in enumerate(board_views):
        cv2.imwrite(str(d / "board" / f"v{k:02d}.png"), img)
    return d


def snapshot(d) -> dict[str, str]:
    return {
        str(p.relative_to(d)): hashlib.sha1(p.read_bytes()).hexdigest() if p.is_file() else "folder"
        for p in sorted(d.rglob("*"))
    }


def one_line_exit_2(capsys, argv, *needles) -> str:
    rc = main([str(a) for a in argv])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2, err
    assert len(err) == 1 and "Traceback" not in err[0], err
    for n in needles:
        assert n in err[0], err[0]
    return err[0]


# (command line with {d} for the folder of inputs, the output that is an input)
SAME = [
    ("fusion run {d}/in.mcap --out {d}/in.mcap --force --quiet", "in.mcap"),
    ("fusion run {d}/in.mcap --out {d}/board/../././in.mcap --force --quiet", "board/../././in.mcap"),
    ("fusion run {d}/in.mcap --calibration {d}/cal.yaml --out {d}/cal.yaml --force --quiet", "cal.yaml"),
    ("fusion attitude {d}/imu.csv {d}/imu.csv --force", "imu.csv"),
    ("calibrate block {d}/in.mcap --out {d}/in.mcap --force", "in.mcap"),
    ("calibrate block {d}/in.mcap --prior {d}/cal.yaml --out {d}/cal.yaml --force", "cal.yaml"),
    ("calibrate latency {d}/in.mcap --out {d}/in.mcap --force", "in.mcap"),
    ("calibrate hand-eye {d}/poses.csv --out {d}/poses.csv --force", "poses.csv"),
    ("calibrate hand-eye {d}/poses.csv --base {d}/cal.yaml --out {d}/cal.yaml --force", "cal.yaml"),
    ("calibrate intrinsics {d}/board --out {d}/board/v00.png --force", "board/v00.png"),
    ("calibrate intrinsics {d}/board --base {d}/cal.yaml --out {d}/cal.yaml --force", "cal.yaml"),
    ("vision run {d}/in.mcap --out {d}/in.mcap --force --quiet --threads 1 --workers 1", "in.mcap"),
    ("vision train {d}/in.mcap --out {d}/in.mcap --force --epochs 1 --batch 2 --device cpu --threads 1", "in.mcap"),
    ("evaluate {d}/in.mcap --estimate {d}/est.mcap --json {d}/in.mcap --force", "in.mcap"),
    ("evaluate {d}/in.mcap --estimate {d}/est.mcap --json {d}/est.mcap --force", "est.mcap"),
]


@pytest.mark.parametrize("line,out", SAME, ids=[s[0].split(" {d}")[0] + f" -> {s[1]}" for s in SAME])
def test_an_output_that_is_an_input_is_refused_even_with_force(files, capsys, line, out):
    before = snapshot(files)
    one_line_exit_2(capsys, line.format(d=files).split(), f"{files / out}: is also an input of this command")
    assert snapshot(files) == before


def test_a_symlink_or_hard_link_to_an_input_is_the_input(files, capsys):
    os.symlink(files / "in.mcap", files / "link.mcap")
    os.link(files / "in.mcap", files / "hard.mcap")
    before = snapshot(files)
    for name in ("link.mcap", "hard.mcap"):
        argv = ["fusion", "run", files / "in.mcap", "--out", files / name, "--force", "--quiet"]
        one_line_exit_2(capsys, argv, f"{files / name}: is also an input", f"the MCAP file {files / 'in.mcap'}")
    assert snapshot(files) == before and (files / "link.mcap").is_symlink()


def test_a_scenario_file_is_never_replaced_by_the_session(tmp_path, capsys):
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text("base: sweeps\nduration_s: 2\n")
    before = scenario.read_bytes()
    argv = ["sim", "generate", "--scenario", scenario, "--quiet", "--out", scenario, "--force"]
    one_line_exit_2(capsys, argv, f"{scenario}: is also an input of this command (the scenario file)")
    assert scenario.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["scenario.yaml"]


def test_a_pipe_is_never_replaced_by_an_output(tmp_path, capsys):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for force in ([], ["--force"]):
        argv = ["sim", "generate", "--scenario", "sweeps", "--duration", "2", "--quiet", "--out", fifo, *force]
        one_line_exit_2(capsys, argv, f"{fifo}: not a regular file")
    assert stat.S_ISFIFO(fifo.lstat().st_mode) and [p.name for p in tmp_path.iterdir()] == ["fifo"]


def damaged(src, dst, kind: str):
    """A copy of `src` with the damage the field meets: 64 bytes inverted inside a chunk, junk
    appended after the end, the last 4 bytes cut off."""
    data = bytearray(src.read_bytes())
    if kind == "flip":
        c = read_summary(src).chunk_indexes[0]
        mid = c.chunk_start_offset + c.chunk_length // 2
        data[mid : mid + 64] = bytes(b ^ 0xFF for b in data[mid : mid + 64])
    elif kind == "appended":
        data += b"this is not MCAP " * 40
    else:
        data = data[:-4]
    dst.write_bytes(bytes(data))
    return dst


# (command line with {bad} for the damaged copy, the file it is a copy of)
DAMAGED = [
    ("fusion run {bad} --out {d}/o.mcap --quiet", "in.mcap"),
    ("sim report {bad}", "in.mcap"),
    ("evaluate {bad} --estimate {d}/est.mcap --json {d}/o.json", "in.mcap"),
    ("evaluate {d}/in.mcap --estimate {bad} --json {d}/o.json", "est.mcap"),
    ("calibrate block {bad} --out {d}/o.yaml", "in.mcap"),
    ("info {bad}", "in.mcap"),
]


@pytest.mark.parametrize("kind", ["flip", "appended", "cut4"])
@pytest.mark.parametrize("line,src", DAMAGED, ids=[f"{s.split(' {')[0]} {src}" for s, src in DAMAGED])
def test_a_damaged_mcap_is_one_line_naming_where_and_the_way_out(files, capsys, line, src, kind):
    bad = damaged(files / src, files / f"{kind}.mcap", kind)
    before = snapshot(files)
    argv = line.format(d=files, bad=bad).split()
    rc = main(argv)
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2 and len(err) == 1 and "Traceback" not in err[0], err
    assert f"{bad}: " in err[0] and f"`tiplog record recover {bad}`" in err[0], err[0]
    if kind == "flip":  # inside a compressed chunk: its CRC fails, or the decompressor before it
        assert "damaged at byte" in err[0] and ("CRC" in err[0] or "unreadable record" in err[0]), err[0]
    assert snapshot(files) == before


def test_vision_run_refuses_a_damaged_chunk(files, capsys):
    bad = damaged(files / "in.mcap", files / "flip.mcap", "flip")
    before = snapshot(files)
    argv = ["vision", "run", bad, "--out", files / "o.mcap", "--quiet", "--threads", "1", "--workers", "1"]
    one_line_exit_2(capsys, argv, f"{bad}: damaged at byte", "CRC", f"tiplog record recover {bad}")
    assert snapshot(files) == before


def replay(path) -> subprocess.CompletedProcess:
    """`tiplog replay PATH` as fast as it goes, in a process of its own on a peer session."""
    argv = ["replay", str(path), "--max", "--wait", "0", "--mode", "peer", "-l", f"tcp/127.0.0.1:{free_port()}"]
    return subprocess.run(
        [sys.executable, "-m", "tiplog.cli", *argv],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_replay_stops_at_a_damaged_chunk_with_exit_2(files):
    bad = damaged(files / "in.mcap", files / "flip.mcap", "flip")
    r = replay(bad)
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(err) == 1, r.stderr
    assert f"{bad}: damaged at byte" in err[0] and f"tiplog record recover {bad}" in err[0], err[0]


@pytest.mark.parametrize("kind", ["appended", "cut4"])
def test_replay_refuses_a_whole_recording_with_a_damaged_end_as_fusion_run_does(files, capsys, kind):
    """Its data is intact, only what follows it is not: replay played it with exit 0 and no
    word while every other reader refused it; now it gives their line, before joining the bus."""
    bad = damaged(files / "in.mcap", files / f"{kind}.mcap", kind)
    fusion = one_line_exit_2(capsys, ["fusion", "run", bad, "--out", files / "o.mcap", "--quiet"])
    r = replay(bad)
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(err) == 1 and "replayed" not in r.stdout, (r.stdout, r.stderr)
    assert err[0].removeprefix("tiplog replay: ") == fusion.removeprefix("tiplog fusion: ")
    if kind == "appended":  # how many bytes follow the end, and where it is
        end = (files / "in.mcap").stat().st_size
        assert f"{bad}: {bad.stat().st_size - end} bytes after the end of its MCAP data (byte {end})" in err[0]
    assert f"`tiplog record recover {bad}`" in err[0]


def test_record_recover_still_salvages_a_damaged_file(files, capsys):
    for kind in ("flip", "appended"):
        bad = damaged(files / "in.mcap", files / f"{kind}.mcap", kind)
        out = files / f"{kind}.fixed.mcap"
        assert main(["record", "recover", str(bad), "--out", str(out)]) == 0
        assert main(["info", str(out)]) == 0
    capsys.readouterr()
    n = read_summary(files / "appended.fixed.mcap").statistics.message_count
    assert n == read_summary(files / "in.mcap").statistics.message_count  # junk after the end: nothing lost


@pytest.fixture
def small_files(tmp_path, board_views):
    """The inputs of hand-eye, intrinsics and attitude without a bench session: a pose CSV, a
    calibration file, chessboard images, an MCAP file of camera images and an IMU CSV."""
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    from services.bench.scenario import load_scenario
    from services.bench.simulation import as_calibrated_constants
    from tiplog.mcap_io import McapWriter

    d = tmp_path / "d"
    (d / "board").mkdir(parents=True)
    write_pose_csv(d / "poses.csv", *_poses(10, 30, _true_camera()))
    Calibration.from_dict(as_calibrated_constants(load_scenario("static"), 1).to_dict()).save_yaml(d / "cal.yaml")
    with McapWriter(d / "images.mcap") as w:
        for k, img in enumerate(board_views):
            cv2.imwrite(str(d / "board" / f"v{k:02d}.png"), img)
            h, wd = img.shape
            w.write("camera/image", RawImage(width=wd, height=h, encoding="mono8", step=wd, data=img.tobytes()), k)
    rows = ["t_s,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"] + [f"{i / 100},0,0,0,0,0,9.81" for i in range(50)]
    (d / "imu.csv").write_text("\n".join(rows) + "\n")
    return d


# (command line, the output that is an input, the functions that do the command's work)
BEFORE_WORK = [
    ("calibrate hand-eye {d}/poses.csv --out {d}/poses.csv --force", "poses.csv", "hand_eye"),
    ("calibrate hand-eye {d}/poses.csv --base {d}/cal.yaml --out {d}/cal.yaml --force", "cal.yaml", "hand_eye"),
    ("calibrate intrinsics {d}/board --out {d}/board/v03.png --force", "board/v03.png", "intrinsics"),
    ("calibrate intrinsics {d}/board --base {d}/cal.yaml --out {d}/cal.yaml --force", "cal.yaml", "intrinsics"),
    ("calibrate intrinsics {d}/images.mcap --out {d}/images.mcap --force", "images.mcap", "intrinsics"),
    ("fusion attitude {d}/imu.csv {d}/imu.csv --force", "imu.csv", "attitude"),
]
WORK = {
    "hand_eye": ["tiplog.calibration.hand_eye.read_pose_csv", "tiplog.calibration.hand_eye.fit_hand_eye"],
    "intrinsics": [
        "tiplog.calibration.intrinsics.iter_gray",
        "tiplog.calibration.intrinsics.find_corners",
    ],
    "attitude": ["services.fusion.attitude.cli.read_csv", "services.fusion.attitude.filter.estimate"],
}


@pytest.mark.parametrize("line,out,work", BEFORE_WORK, ids=[f"{s.split(' {d}')[0]} -> {o}" for s, o, _ in BEFORE_WORK])
def test_an_output_that_is_an_input_is_refused_before_any_work(small_files, capsys, monkeypatch, line, out, work):
    """The refusal comes before the data is read or fitted: the user does not wait for a fit
    whose result could not be written."""
    started: list[str] = []

    def work_started(target: str):
        def fake(*args, **kwargs):
            started.append(target)
            raise RuntimeError(f"{target} ran before --out was checked")

        return fake

    for target in WORK[work]:
        monkeypatch.setattr(target, work_started(target))
    before = snapshot(small_files)
    one_line_exit_2(
        capsys, line.format(d=small_files).split(), f"{small_files / out}: is also an input of this command"
    )
    assert started == []
    assert snapshot(small_files) == before
