"""One simulated pass as the live bench plays it, and the cache that spares a restarted bench
simulating it again.

Simulating a pass takes seconds (Pinocchio, the sensor and vision models: about 7 s for the
demo's 120 s pass on two cores) and importing those models about 1.5 s more. A bench that
`tiplog up` restarts would leave the system without device streams all that time. So the
first start stores what playing needs, as arrays, in `pass_cache_dir` under a key of everything
the pass depends on (scenario and its file, overrides, seed, duration, tier, and the sources of
the bench and of `tiplog`), and a start with the same key loads it in a fraction of a second,
importing none of the models. The pixel tier renders from the whole session: it is stored
beside, and loaded on the camera thread, so that the device and robot streams flow before the
first frame does. The newest `KEEP` passes are kept.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tiplog.geometry.camera import CameraModel

log = logging.getLogger(__name__)

FORMAT = 1  # bump when Playback changes shape
KEEP = 4
ROOT = Path(__file__).resolve().parents[2]
SOURCES = (("services/bench", "**/*.py"), ("services/bench", "**/*.yaml"), ("tiplog", "*.py"))


@dataclass
class PlayStream:
    """One device stream: device stamp and host arrival [ns, from the pass start], values."""

    device_ns: np.ndarray
    arrival_ns: np.ndarray
    values: np.ndarray
    status: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.arrival_ns)


@dataclass
class PlayTruth:
    """The robot's ground truth at 1 kHz: time from the pass start [ns], base frame, metres."""

    t_ns: np.ndarray
    rcm_base_m: np.ndarray
    R_base_tool: np.ndarray
    p_tip_base_m: np.ndarray
    q_rad: np.ndarray
    dq_radps: np.ndarray
    trial: np.ndarray
    phase: np.ndarray


@dataclass
class PlayFrames:
    """Per camera frame, from the pass start [ns]: shown instant, capture stamp, publish time."""

    t_true_ns: np.ndarray
    capture_ns: np.ndarray
    publish_ns: np.ndarray


@dataclass
class Playback:
    """What `services.bench.live.LiveBench` plays."""

    scenario_name: str
    tier: str  # measurement or pixel (the simulation's tier)
    streams: dict[str, PlayStream]
    gt: PlayTruth
    T_base_camera: np.ndarray
    clock_offset_ns: int
    camera: CameraModel
    camera_frames: PlayFrames
    vision_payloads: list[bytes]
    device_rates_hz: dict[str, float]
    calibration_yaml: str | None = None  # the as-calibrated file the first start wrote
    session_pickle: bytes | None = None  # pixel tier, in the cache: the session to render from
    session: Any = None  # pixel tier: the SimulatedSession, once loaded

    @classmethod
    def from_session(cls, sim: Any, calibration_yaml: str | None = None) -> Playback:
        """From a `SimulatedSession` just simulated (nothing rendered from it yet)."""
        gt = sim.gt
        sc = sim.scenario
        return cls(
            scenario_name=sc.name,
            tier=sim.tier,
            streams={
                n: PlayStream(s.device_ns, s.arrival_ns, s.values, s.status, dict(s.extra))
                for n, s in sim.streams.items()
            },
            gt=PlayTruth(
                gt.t_ns,
                np.asarray(gt.rcm_base_m, float),
                gt.R_base_tool,
                gt.p_tip_base_m,
                gt.q_rad,
                gt.dq_radps,
                gt.trial,
                gt.phase,
            ),
            T_base_camera=np.asarray(sim.truth.T_base_camera, float),
            clock_offset_ns=int(sim.clock.offset_ns),
            camera=sc.camera.model(),
            camera_frames=PlayFrames(
                sim.camera_frames.t_true_ns, sim.camera_frames.capture_ns, sim.camera_frames.publish_ns
            ),
            vision_payloads=list(sim.vision_payloads),
            device_rates_hz={
                "gyro": sc.gyro.rate_hz,
                "accel": sc.accel.rate_hz,
                "tof": sc.tof.rate_hz,
                "mag": sc.mag.rate_hz,
            },
            calibration_yaml=calibration_yaml,
            session=sim if sim.tier == "pixel" else None,
        )

    def load_session(self) -> None:
        """Pixel tier: the session to render from, unpickled from the cache when not already
        here (imports the bench's models: about 1.5 s)."""
        if self.session is None and self.session_pickle is not None:
            self.session = pickle.loads(self.session_pickle)
            self.session_pickle = None

    def render_frame(self, k: int) -> np.ndarray:
        """Pixel tier: frame k, uint8 (H, W, 3) RGB."""
        self.load_session()
        if self.session is None:
            raise ValueError("this pass was simulated for the measurement tier: it has no frames to render")
        return self.session.render_frame(k)


def cache_key(scenario: str, overrides: list[str], seed: int, duration_s: float | None, tier: str) -> str:
    """Hex digest of everything a pass depends on."""
    h = hashlib.sha256(json.dumps([FORMAT, scenario, list(overrides), seed, duration_s, tier]).encode())
    scenario_file = Path(scenario)
    if scenario_file.is_file():
        h.update(scenario_file.read_bytes())
    for folder, pattern in SOURCES:
        for p in sorted((ROOT / folder).glob(pattern)):
            if "__pycache__" not in p.parts:
                h.update(p.relative_to(ROOT).as_posix().encode())
                h.update(p.read_bytes())
    return h.hexdigest()[:32]


def cache_path(cache_dir: str, key: str) -> Path:
    return Path(os.path.expanduser(cache_dir)) / f"{key}.pass"


def load(path: Path) -> Playback | None:
    """The cached pass at `path`, or None (absent, or unreadable: logged, then simulated anew)."""
    try:
        with open(path, "rb") as f:
            play = pickle.load(f)
        if not isinstance(play, Playback):
            raise TypeError(f"holds a {type(play).__name__}")
    except FileNotFoundError:
        return None
    except Exception as e:  # a cut or stale file must never stop the bench
        log.warning("bench pass cache %s unreadable (%s): simulating", path, e)
        return None
    with contextlib.suppress(OSError):
        os.utime(path)  # the newest used is kept longest
    return play


def store(path: Path, play: Playback) -> None:
    """Write `play` (with its session, pixel tier) under a temporary name renamed when complete,
    then keep only the newest `KEEP` passes in the folder. A folder that cannot be written is
    logged: the bench runs on, and a restart simulates again."""
    keep = dataclasses.replace(play, session=None)
    if play.session is not None:
        keep.session_pickle = pickle.dumps(play.session, protocol=pickle.HIGHEST_PROTOCOL)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            pickle.dump(keep, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
        passes = sorted(path.parent.glob("*.pass"), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in passes[KEEP:]:
            old.unlink(missing_ok=True)
    except OSError as e:
        log.warning("bench pass cache %s not written (%s): a restart will simulate again", path, e)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
