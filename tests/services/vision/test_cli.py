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
    assert "frames/s" in capsys.readouterr().err

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
    assert main(["vision", "run", str(recording), "--out", str(tmp_path / "o.mcap"), "--workers", "0"]) == 2
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
