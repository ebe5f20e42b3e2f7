"""`tiplog vision run` and `tiplog vision train` on a short pixel-tier bench recording."""

from __future__ import annotations

import numpy as np
import pytest

from tiplog.cli import main
from tiplog.mcap_io import read_messages, read_metadata


def _obs(path):
    return [r for r in read_messages(path, ["vision/observation"])]


def _geometry(o) -> tuple:
    return (o.header.stamp_ns, o.accepted, o.reject_reason, o.n_left.x, o.n_left.y, o.n_right.z, o.junction_u_px,
            o.junction_ray.z, o.axis_point_m.z, o.mask_iou, o.lateral_px)  # fmt: skip


def test_run_writes_one_observation_per_frame_at_its_capture_stamp(recording, tmp_path, capsys):
    out = tmp_path / "obs.mcap"
    assert main(["vision", "run", str(recording), "--out", str(out)]) == 0
    stamps = [r.message.timestamp.ToNanoseconds() for r in read_messages(recording, ["camera/image"])]
    obs = _obs(out)
    assert [r.message.header.stamp_ns for r in obs] == stamps
    assert [r.log_time_ns for r in obs] == stamps
    assert sum(r.message.accepted for r in obs) >= len(obs) // 2
    # a complete session for offline fusion: the device streams and metadata come along, frames do not
    topics = {r.topic for r in read_messages(out)}
    assert {"device/gyro", "camera/info", "vision/observation"} <= topics and "camera/image" not in topics
    assert "calibration_as_calibrated" in read_metadata(out)
    err = capsys.readouterr().err
    assert "frames/s" in err and "\r" not in err  # stderr is no terminal here: no in-place progress

    again = tmp_path / "again.mcap"
    assert main(["vision", "run", str(recording), "--out", str(again), "--quiet"]) == 0
    assert [_geometry(r.message) for r in _obs(again)] == [_geometry(r.message) for r in obs]  # deterministic


def test_run_refuses_to_overwrite_and_names_bad_inputs(recording, tmp_path, capsys):
    out = tmp_path / "obs.mcap"
    out.write_bytes(b"keep me")
    assert main(["vision", "run", str(recording), "--out", str(out)]) == 2
    assert out.read_bytes() == b"keep me"
    assert "use --force" in capsys.readouterr().err
    notmcap = tmp_path / "x.mcap"
    notmcap.write_bytes(b"hello")
    assert main(["vision", "run", str(notmcap), "--out", str(tmp_path / "o.mcap")]) == 2
    assert "not an MCAP file" in capsys.readouterr().err
    assert main(["vision", "run", str(recording), "--out", str(tmp_path / "o.mcap"), "--weights", str(notmcap)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "checkpoint" in err[0]
    with pytest.raises(SystemExit) as e:  # refused while parsing the options
        main(["vision", "run", str(recording), "--out", str(tmp_path / "o.mcap"), "--workers", "0"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--workers" in err[0]
    assert not (tmp_path / "o.mcap").exists()


@pytest.mark.slow
def test_train_writes_a_checkpoint_and_resumes(recording, tmp_path, capsys):
    import torch

    from services.vision.network import load_checkpoint

    torch.set_num_threads(1)
    ck = tmp_path / "net.pt"
    base = ["vision", "train", str(recording), "--out", str(ck), "--batch", "2", "--every", "2", "--device", "cpu"]
    assert main([*base, "--epochs", "1"]) == 0
    err = capsys.readouterr().err
    assert "held out (by pose)" in err and "held-out IoU" in err
    _, extra = load_checkpoint(ck, "cpu")
    assert len(extra["metrics"]["held_out_iou"]) == 1 and extra["metrics"]["train_frames"] > 0
    assert main([*base, "--epochs", "1"]) == 2  # exists: no overwrite without --force
    assert main([*base, "--epochs", "2", "--resume"]) == 0
    assert "resumed after epoch 1" in capsys.readouterr().err
    _, extra = load_checkpoint(ck, "cpu")
    assert len(extra["metrics"]["held_out_iou"]) == 2
    assert np.isfinite(extra["metrics"]["held_out_iou"]).all()


def test_run_without_calibration_says_so(rendered, camera, tmp_path, capsys):
    from tiplog.images import raw_image
    from tiplog.mcap_io import McapWriter

    src = tmp_path / "frames.mcap"
    with McapWriter(src) as w:
        w.write("camera/info", camera.to_calibration(0), log_time_ns=0)
        w.write("camera/image", raw_image(rendered[0][0], 10), log_time_ns=10)
    out = tmp_path / "obs.mcap"
    assert main(["vision", "run", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no calibration" in err[0] and "--calibration" in err[0]
    assert not out.exists()


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["train", "r.mcap", "--out", "n.pt", "--seed", "-5"], ("--seed", ">= 0")),
        (["train", "r.mcap", "--out", "n.pt", "--lr", "inf"], ("--lr", "finite")),
        (["train", "r.mcap", "--out", "n.pt", "--lr", "0"], ("--lr", "> 0")),
        (["train", "r.mcap", "--out", "n.pt", "--input-step", "1000"], ("--input-step", "<= 22")),
        (["train", "r.mcap", "--out", "n.pt", "--batch", "1"], ("--batch", ">= 2")),
        (["train", "r.mcap", "--out", "n.pt", "--threads", "-1"], ("--threads", ">= 0")),
        (["run", "r.mcap", "--out", "o.mcap", "--threads", "5000"], ("--threads", "<=")),
        (["run", "r.mcap", "--out", "o.mcap", "--threads", "100000"], ("--threads", "<=")),
        (["run", "r.mcap", "--out", "o.mcap", "--threads", "-1"], ("--threads", ">= 0")),
        (["run", "r.mcap", "--out", "o.mcap", "--workers", "0"], ("--workers", ">= 1")),
    ],
)
def test_option_values_are_refused_while_parsing(argv, needles, capsys):
    with pytest.raises(SystemExit) as e:
        main(["vision", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1, err
    for n in needles:
        assert n in err[0], err[0]


def test_train_refuses_too_few_frames_and_an_unreadable_resume_state(recording, tmp_path, capsys):
    import torch

    ck = tmp_path / "net.pt"
    base = ["vision", "train", str(recording), "--out", str(ck), "--batch", "2", "--device", "cpu", "--threads", "1"]

    def one_line(*needles):
        err = capsys.readouterr().err.strip().splitlines()
        assert err and "Traceback" not in "".join(err), err
        for n in needles:
            assert n in err[-1], err[-1]

    assert main([*base, "--every", "1000"]) == 2  # one labelled frame: nothing left to hold out
    one_line("--every 1000", "1 labelled frame", "at least 2")
    state = tmp_path / "net.pt.resume"
    state.write_bytes(b"PK\x03\x04" + bytes(100))  # the start of a zip, cut short
    assert main([*base, "--every", "5", "--resume"]) == 2
    one_line(str(state), "not a readable training state")
    torch.save({"something": "else"}, state)  # a whole file, but not a training state
    assert main([*base, "--every", "5", "--resume"]) == 2
    one_line(str(state), "not a training state this run can continue")
    assert not ck.exists()
    # --resume replaces <out> only when there is a state to continue; otherwise it needs --force
    state.unlink()
    ck.write_bytes(b"someone else's checkpoint")
    assert main([*base, "--every", "5", "--resume"]) == 2
    one_line(str(ck), "use --force")
    assert ck.read_bytes() == b"someone else's checkpoint"
