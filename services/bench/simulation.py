"""One simulated session in memory: robot truth, device streams and camera, before any output.

Offline generation (session.py) writes it to MCAP; the live bench (live.py) plays it against
the host clock. Both go through `simulate_session`, so live and offline sessions of the same
scenario and seed carry the same samples.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from services.bench.scenario import Scenario
from services.bench.sensors.calibration import as_calibrated, true_constants
from services.bench.sensors.device import DeviceClock, Kinematics, Stream, _interp, _interp_R, arrival, simulate_sensors
from services.bench.sensors.vision_model import VisionFrames, frame_times, simulate_vision

TIERS = ("measurement", "pixel")


@dataclass
class CameraFrames:
    """Per frame, relative to the session start [ns]: the instant shown, the capture stamp
    (arrival on the host), and when the result is published (capture for pixel frames,
    processing done for measurement-tier observations)."""

    t_true_ns: np.ndarray
    capture_ns: np.ndarray
    publish_ns: np.ndarray


@dataclass
class SimulatedSession:
    scenario: Scenario
    seed: int
    tier: str
    motion_cfg: Any
    truth: Any  # BenchConstants, evaluation only
    calib: Any  # as-calibrated constants, for estimators
    gt: Any  # motion.GroundTruth
    kin: Kinematics
    clock: DeviceClock
    streams: dict[str, Stream]
    camera_frames: CameraFrames
    vision: VisionFrames | None = None  # measurement tier
    vision_payloads: list[bytes] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)  # wall seconds per stage
    _render_rng: np.random.Generator | None = None
    _render_params: Any = None
    _render_session: Any = None

    def frame_pose_cam(self, k: int) -> np.ndarray:
        """T_camera_tool (4x4) at the instant frame k shows."""
        return self.pose_cam(self.camera_frames.t_true_ns[k : k + 1])

    def pose_cam(self, t_ns: np.ndarray) -> np.ndarray:
        """T_camera_tool (4x4) at the session time t_ns ((1,) array) [ns]."""
        T = np.eye(4)
        T[:3, :3] = _interp_R(t_ns, self.kin.t_ns, self.kin.R_base_tool)[0]
        T[:3, 3] = _interp(t_ns, self.kin.t_ns, self.kin.p_tip_base_m)[0]
        return np.linalg.inv(self.truth.T_base_camera) @ T

    def render_frame(self, k: int) -> np.ndarray:
        """Pixel tier: frame k as uint8 (H, W, 3) RGB, integrated over the exposure (render.exposure_ms)
        centred on the instant the frame shows."""
        from services.bench.render import renderer as render
        from services.bench.render.effects import RenderSession

        sc = self.scenario
        if self._render_params is None:
            self._render_params = sc.render.model_copy(
                update={
                    "shaft_radius_m": sc.instrument.shaft_radius_m,
                    "junction_from_tip_mm": max(2.0, sc.instrument.junction_proximal_m * 1e3),
                }
            )
            # its own stream of the seed: every other draw of the session is what it was without it
            s_render = np.random.SeedSequence(self.seed).spawn(5)[4]
            self._render_session = RenderSession.create(
                sc.camera.model(),
                self._render_params,
                float(self.kin.t_ns[-1]) * 1e-9,
                self._render_params.junction_from_tip_mm * 1e-3,
                np.random.default_rng(s_render),
            )
        assert self._render_rng is not None
        p = self._render_params
        t_ns = int(self.camera_frames.t_true_ns[k])
        if p.exposure_ms > 0:
            m = p.exposure_subframes_max + (p.exposure_subframes_max % 2 == 0)
            t_sub = np.clip(t_ns + np.round(np.linspace(-0.5, 0.5, m) * p.exposure_ms * 1e6), 0, self.kin.t_ns[-1])
            T = np.stack([self.pose_cam(t_sub[i : i + 1]) for i in range(m)])
        else:
            T = self.frame_pose_cam(k)
        return render.render_frame(
            sc.camera.model(), T, p, self._render_rng, t_s=t_ns * 1e-9, session=self._render_session
        )


def commanded_through_hand_eye(scenario: Scenario, truth: Any, calib: Any) -> Any:
    """The paper commanded trials along camera axes through its estimated hand-eye: unless the
    scenario sets motion.command_camera_error_deg itself, use the as-calibrated camera
    rotation (R_cmd = R_true E, E = R_true^T R_cal)."""
    mc = scenario.motion
    if not hasattr(mc, "command_camera_error_deg") or any(abs(v) > 0 for v in mc.command_camera_error_deg):
        return mc
    E = truth.T_base_camera[:3, :3].T @ calib.T_base_camera[:3, :3]
    rpy = Rotation.from_matrix(E).as_euler("xyz", degrees=True)  # R = Rz Ry Rx, as rpy_to_matrix
    return mc.model_copy(update={"command_camera_error_deg": tuple(float(v) for v in rpy)})


def as_calibrated_constants(scenario: Scenario, seed: int = 0) -> Any:
    """The as-calibrated constants `simulate_session(scenario, seed)` will carry, without
    simulating (the live bench writes them to its calibration file at start-up)."""
    s_cal = np.random.SeedSequence(seed).spawn(4)[1]
    return as_calibrated(true_constants(scenario), scenario, np.random.default_rng(s_cal))


def shortest_duration(scenario: Scenario) -> tuple[float, str, float]:
    """(seconds, stream, its rate): the shortest cut of the protocol that holds one sample of
    every device stream. The sampler leaves 1 ms at the end of the robot's 1 kHz timeline,
    which itself ends 1 ms short: the slowest stream's period plus 3 ms (measured: the ToF at
    100 Hz needs 13 ms, at 2 Hz 503 ms; shorter cuts had a stream with no sample and crashed)."""
    rates = {name: getattr(scenario, name).rate_hz for name in ("gyro", "accel", "tof", "mag")}
    name = min(rates, key=rates.__getitem__)
    return math.ceil((1.0 / rates[name] + 0.003) * 1e3 - 1e-6) / 1e3, name, rates[name]


def duration_problem(scenario: Scenario, duration_s: float | None, what: str) -> str | None:
    """What is wrong with playing `duration_s` seconds of `scenario` (a setting named `what`),
    in the words of `tiplog sim generate` and the live bench, or None (see `shortest_duration`)."""
    shortest, stream, rate = shortest_duration(scenario)
    if duration_s is None or duration_s >= shortest:
        return None
    return f"{what}: {duration_s:g} s holds no sample of the {stream} stream at {rate:g} Hz; give at least {shortest:.3f} s"


def simulate_session(
    scenario: Scenario, seed: int = 0, tier: str = "measurement", duration_s: float | None = None
) -> SimulatedSession:
    """Robot, sensors and camera for `scenario` (seeded; `duration_s` cuts the protocol)."""
    from services.bench.robot import motion  # Pinocchio: imported only when simulating

    if tier not in TIERS:
        raise ValueError(f"tier must be one of {', '.join(TIERS)} (got {tier!r})")
    t0 = time.perf_counter()
    duration = duration_s if duration_s is not None else scenario.duration_s
    s_motion, s_cal, s_sens, s_vis = np.random.SeedSequence(seed).spawn(4)
    truth = true_constants(scenario)
    calib = as_calibrated(truth, scenario, np.random.default_rng(s_cal))
    motion_cfg = commanded_through_hand_eye(scenario, truth, calib)
    gt = motion.simulate(motion_cfg, scenario.protocol, int(s_motion.generate_state(1)[0]), duration)
    truth.rcm_base_m = np.asarray(gt.rcm_base_m, dtype=float)
    t_robot = time.perf_counter()
    kin, clock, streams = simulate_sensors(gt, scenario, truth, np.random.default_rng(s_sens))
    vrng = np.random.default_rng(s_vis)
    sim = SimulatedSession(scenario, seed, tier, motion_cfg, truth, calib, gt, kin, clock, streams, None)  # type: ignore[arg-type]
    if tier == "measurement":
        from services.bench import messages

        v = simulate_vision(kin, scenario, truth, vrng)
        sim.vision = v
        sim.camera_frames = CameraFrames(v.t_true_ns, v.capture_ns, v.processed_ns)
        sim.vision_payloads = messages.vision(v).payloads
    else:
        t = frame_times(scenario, int(kin.t_ns[-1]), vrng)
        cap = arrival(t, scenario.camera.latency_ms, scenario.camera.latency_jitter_ms, vrng)
        sim.camera_frames = CameraFrames(t, cap, cap)
        sim._render_rng = vrng
    sim.timings = {"robot_s": t_robot - t0, "models_s": time.perf_counter() - t_robot}
    return sim
