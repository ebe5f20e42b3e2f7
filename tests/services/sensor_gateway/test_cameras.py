"""Camera sources: OpenCV on a video file it wrote itself (MJPG in .avi), a folder of
images, RealSense through a fake `pyrealsense2` at the SDK seam (and the real SDK when it
is installed), and the calibration file."""

from __future__ import annotations

import sys
import types
from pathlib import Path

import cv2
import numpy as np
import pytest

from services.sensor_gateway.cameras import (
    CameraReadError,
    DeviceAlreadyConnectedError,
    DeviceNotConnectedError,
    EndOfStreamError,
    FolderCamera,
    FolderCameraConfig,
    OpenCVCamera,
    OpenCVCameraConfig,
    RealSenseCamera,
    RealSenseCameraConfig,
)
from services.sensor_gateway.cameras.calibration import CalibrationError, load_calibration, to_message

W, H = 64, 48
# BGR colours, far apart so that JPEG keeps them recognisable.
COLOURS_BGR = [(0, 0, 255), (0, 255, 0), (255, 0, 0), (255, 255, 255), (0, 0, 0)]


def _image(k: int) -> np.ndarray:
    img = np.zeros((H, W, 3), np.uint8)
    img[:] = COLOURS_BGR[k % len(COLOURS_BGR)]
    img[0, 0] = (k, k, k)  # a per-frame mark (exact only for lossless files)
    return img


def write_video(path: Path, n: int) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (W, H))
    assert writer.isOpened(), "OpenCV cannot write MJPG/AVI here"
    for k in range(n):
        writer.write(_image(k))
    writer.release()
    return path


def write_folder(folder: Path, n: int) -> Path:
    folder.mkdir()
    for k in range(n):
        cv2.imwrite(str(folder / f"frame_{k:04d}.png"), _image(k))
    (folder / "notes.txt").write_text("not an image")
    return folder


# OpenCV ---------------------------------------------------------------------------
def test_opencv_reads_a_video_file_in_rgb_with_arrival_stamps(tmp_path):
    path = write_video(tmp_path / "clip.avi", 5)
    with OpenCVCamera(OpenCVCameraConfig(source=str(path))) as cam:
        frames = [cam.read() for _ in range(5)]
        with pytest.raises(EndOfStreamError):
            cam.read()
    assert [f.seq for f in frames] == [0, 1, 2, 3, 4]
    assert all(f.image.shape == (H, W, 3) and f.encoding == "rgb8" for f in frames)
    stamps = [f.stamp_ns for f in frames]
    assert stamps == sorted(stamps) and stamps[0] > 0
    for k, f in enumerate(frames):  # colours come back in RGB order
        want_rgb = COLOURS_BGR[k][::-1]
        assert np.abs(f.image[H // 2, W // 2].astype(int) - want_rgb).max() < 20


def test_opencv_bgr_and_loop(tmp_path):
    path = write_video(tmp_path / "clip.avi", 3)
    with OpenCVCamera(OpenCVCameraConfig(source=str(path), color="bgr", loop=True)) as cam:
        frames = [cam.read() for _ in range(7)]
    assert all(f.encoding == "bgr8" for f in frames)
    assert np.abs(frames[3].image[H // 2, W // 2].astype(int) - COLOURS_BGR[0]).max() < 20


def test_opencv_async_read_returns_frames(tmp_path):
    path = write_video(tmp_path / "clip.avi", 30)
    with OpenCVCamera(OpenCVCameraConfig(source=str(path), pace=True, fps=100)) as cam:
        a = cam.async_read(2000)
        b = cam.async_read(2000)
    assert b.seq > a.seq and b.stamp_ns > a.stamp_ns


def test_opencv_errors(tmp_path):
    cam = OpenCVCamera(OpenCVCameraConfig(source=str(tmp_path / "missing.avi")))
    with pytest.raises(DeviceNotConnectedError):
        cam.read()
    with pytest.raises(CameraReadError, match="cannot open"):
        cam.connect()
    path = write_video(tmp_path / "clip.avi", 2)
    with OpenCVCamera(OpenCVCameraConfig(source=str(path))) as cam:
        with pytest.raises(DeviceAlreadyConnectedError):
            cam.connect()
    assert not cam.is_connected
    with pytest.raises(ValueError, match="color"):
        OpenCVCameraConfig(color="yuv")


# Folder ---------------------------------------------------------------------------
def test_folder_reads_images_in_name_order_exactly(tmp_path):
    folder = write_folder(tmp_path / "imgs", 4)
    with FolderCamera(FolderCameraConfig(path=str(folder), color="bgr")) as cam:
        frames = [cam.read() for _ in range(4)]
        with pytest.raises(EndOfStreamError):
            cam.read()
    for k, f in enumerate(frames):
        np.testing.assert_array_equal(f.image, _image(k))  # PNG: lossless
    with FolderCamera(FolderCameraConfig(path=str(folder))) as cam:
        f = cam.read()
    np.testing.assert_array_equal(f.image, _image(0)[..., ::-1])
    assert f.encoding == "rgb8"


def test_folder_errors(tmp_path):
    with pytest.raises(CameraReadError, match="does not exist"):
        FolderCamera(FolderCameraConfig(path=str(tmp_path / "nope"))).connect()
    (tmp_path / "empty").mkdir()
    with pytest.raises(CameraReadError, match="holds no"):
        FolderCamera(FolderCameraConfig(path=str(tmp_path / "empty"))).connect()
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "a.png").write_bytes(b"not a png")
    with FolderCamera(FolderCameraConfig(path=str(bad))) as cam, pytest.raises(CameraReadError, match="not a readable"):
        cam.read()


# RealSense ------------------------------------------------------------------------
def fake_pyrealsense2(image_rgb: np.ndarray, fail_after: int | None = None) -> types.ModuleType:
    """The slice of the pyrealsense2 API the source uses, recording how it was called."""
    rs = types.ModuleType("pyrealsense2")
    rs.calls = []
    rs.stream = types.SimpleNamespace(color="stream.color", depth="stream.depth")
    rs.format = types.SimpleNamespace(rgb8="format.rgb8")
    rs.option = types.SimpleNamespace(enable_auto_exposure="opt.ae", exposure="opt.exposure", gain="opt.gain")

    class Profile:
        def __init__(self, kind):
            self.kind = kind

        def stream_type(self):
            return self.kind

    class Sensor:
        def __init__(self, kinds):
            self.kinds = kinds

        def get_stream_profiles(self):
            return [Profile(k) for k in self.kinds]

        def set_option(self, opt, value):
            rs.calls.append(("set_option", opt, value))

    class Intr:
        width, height, fx, fy, ppx, ppy = 1280, 720, 640.5, 641.0, 639.0, 361.0
        model = "distortion.brown_conrady"
        coeffs = [-0.05, 0.06, 0.001, -0.001, -0.02]

    class VideoProfile:
        def as_video_stream_profile(self):
            return self

        def get_intrinsics(self):
            return Intr()

    class Device:
        def query_sensors(self):
            return [Sensor(["stream.depth", "stream.color"])]  # D405: colour from the stereo module

    class PipelineProfile:
        def get_device(self):
            return Device()

        def get_stream(self, kind):
            assert kind == "stream.color"
            return VideoProfile()

    class ColorFrame:
        def get_data(self):
            return image_rgb

        def __bool__(self):
            return True

    class Frames:
        def get_color_frame(self):
            return ColorFrame()

    class config:  # noqa: N801 - the SDK's name
        def enable_stream(self, *args):
            rs.calls.append(("enable_stream", *args))

        def enable_device(self, serial):
            rs.calls.append(("enable_device", serial))

        def enable_device_from_file(self, path, repeat_playback=True):
            rs.calls.append(("from_file", path, repeat_playback))

    class pipeline:  # noqa: N801
        n = 0

        def start(self, cfg):
            rs.calls.append(("start",))
            return PipelineProfile()

        def wait_for_frames(self, timeout_ms):
            pipeline.n += 1
            if fail_after is not None and pipeline.n > fail_after:
                raise RuntimeError("Frame didn't arrive within 1000")
            return Frames()

        def stop(self):
            rs.calls.append(("stop",))

    rs.config, rs.pipeline = config, pipeline
    return rs


def test_realsense_through_a_fake_sdk(monkeypatch):
    img = np.zeros((720, 1280, 3), np.uint8)
    img[..., 0] = 200  # red in RGB
    rs = fake_pyrealsense2(img, fail_after=2)
    monkeypatch.setitem(sys.modules, "pyrealsense2", rs)
    cfg = RealSenseCameraConfig(serial_number="123", exposure_us=5000)
    with RealSenseCamera(cfg) as cam:
        f = cam.read()
        assert f.encoding == "rgb8" and f.image.shape == (720, 1280, 3) and f.image[0, 0, 0] == 200
        cam.read()
        with pytest.raises(CameraReadError, match="didn't arrive"):
            cam.read()
        intr = cam.intrinsics()
    assert ("enable_stream", "stream.color", 1280, 720, "format.rgb8", 15) in rs.calls
    assert ("enable_device", "123") in rs.calls
    assert ("set_option", "opt.ae", 0) in rs.calls and ("set_option", "opt.exposure", 5000.0) in rs.calls
    assert rs.calls[-1] == ("stop",)
    assert intr.K == (640.5, 0.0, 639.0, 0.0, 641.0, 361.0, 0.0, 0.0, 1.0)
    assert intr.distortion_model == "plumb_bob" and len(intr.D) == 5


def test_realsense_bgr_is_converted(monkeypatch):
    img = np.zeros((720, 1280, 3), np.uint8)
    img[..., 0] = 200
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake_pyrealsense2(img))
    with RealSenseCamera(RealSenseCameraConfig(color="bgr")) as cam:
        f = cam.read()
    assert f.encoding == "bgr8" and f.image[0, 0, 2] == 200 and f.image[0, 0, 0] == 0


def test_realsense_without_the_sdk_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # import raises ImportError
    with pytest.raises(CameraReadError, match=r"tiplog\[realsense\]"):
        RealSenseCamera(RealSenseCameraConfig()).connect()


def test_realsense_real_sdk_is_importable_lazily():
    rs = pytest.importorskip("pyrealsense2")
    from services.sensor_gateway.cameras.realsense import import_sdk

    assert import_sdk() is rs


# Calibration ----------------------------------------------------------------------
def test_calibration_file_to_message(tmp_path):
    p = tmp_path / "cal.yaml"
    p.write_text("width: 1280\nheight: 720\nK: [[900, 0, 640], [0, 901, 360], [0, 0, 1]]\nD: [0.1, -0.2, 0, 0, 0.05]\n")
    intr = load_calibration(p)
    m = to_message(intr, 1_500_000_000)
    assert (m.width, m.height, m.distortion_model, m.frame_id) == (1280, 720, "plumb_bob", "camera")
    assert list(m.K) == [900, 0, 640, 0, 901, 360, 0, 0, 1] and list(m.P)[:4] == [900, 0, 640, 0]
    assert (m.timestamp.seconds, m.timestamp.nanos) == (1, 500_000_000)


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("height: 720\nK: [1,0,0,0,1,0,0,0,1]\nD: []\n", "width"),
        ("width: 10\nheight: 10\nK: [1,0,0]\nD: []\n", "K"),
        ("width: 10\nheight: 10\nK: [1,0,0,0,1,0,0,0,1]\nD: [a]\n", "D"),
        ("width: 10\nheight: 10\nK: [1,0,0,0,1,0,0,0,1]\nD: []\ndistortion_model: fisheye9\n", "distortion_model"),
        ("width: -1\nheight: 10\nK: [1,0,0,0,1,0,0,0,1]\nD: []\n", "width"),
    ],
)
def test_bad_calibration_names_the_field(tmp_path, text, field):
    p = tmp_path / "cal.yaml"
    p.write_text(text)
    with pytest.raises(CalibrationError, match=field):
        load_calibration(p)
