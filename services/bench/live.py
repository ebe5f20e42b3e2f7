"""Live bench: a simulated session played out in real time.

One pass of the scenario (robot truth, device streams, camera) is simulated up front with the
same models as offline generation (or loaded from the pass cache, `services.bench.playback`),
then played against the host clock, looping:
- device samples leave through a pseudo-terminal in the device's own serial protocol
  (tiplog.devproto), each written at its simulated host-arrival time, so the gateway's real
  serial path stamps and publishes them;
- camera: pixel tier renders each frame ahead of its time (by the recent render time) and
  publishes camera/image with its capture stamp when it is due, as a camera delivers it;
  measurement tier publishes vision/observation at its processing-done time; camera/info at 1 Hz;
- ground truth on bench/robot (evaluation only) and the tool pose on bench/tf for Foxglove;
- bench/status (a LoadStatus) every `status_period_s`: the camera frames published per second
  against the camera's rate, those skipped because they were due over two frames ago (a renderer
  that cannot keep 15 fps on the cores it gets), and the render time's p95. Falling behind is
  said in one warning line, and again when it catches up.

The camera thread renders at a lower priority (`render_nice`, once its first frame is rendered)
than the device thread, so on a busy machine the pixel tier drops frames rather than delaying the
device's bytes or fusion.

Times in the simulated pass are relative to its start; pass k starts at host time
t0 + k * duration, so stamps stay monotonic across loops.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

from services.bench.playback import Playback
from tiplog import images
from tiplog.bus import Bus
from tiplog.clock import now_ns
from tiplog.devproto.emulator import DeviceEmulator
from tiplog.geometry import rot_to_quat
from tiplog.loadstatus import LoadMeter
from tiplog.priority import lower_this_thread
from tiplog.v1 import robot_pb2, system_pb2, vision_pb2

log = logging.getLogger(__name__)

GYRO, ACCEL, TOF, MAG = range(4)
_STREAMS = ("gyro", "accel", "tof", "mag")


@dataclass
class LiveCounters:
    device_sent: int = 0
    frames_published: int = 0
    frames_skipped_late: int = 0
    robot_published: int = 0
    loops: int = 0


def _device_schedule(sim: Playback) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All device samples in arrival order: (arrival_ns, stream code, index in stream)."""
    t = np.concatenate([sim.streams[n].arrival_ns for n in _STREAMS])
    kind = np.concatenate([np.full(len(sim.streams[n]), i, dtype=np.int8) for i, n in enumerate(_STREAMS)])
    idx = np.concatenate([np.arange(len(sim.streams[n])) for n in _STREAMS])
    order = np.argsort(t, kind="stable")
    return t[order], kind[order], idx[order]


class LiveBench:
    """Plays `sim` in real time until `stop` is set. Threads: device+truth, camera."""

    def __init__(
        self,
        sim: Playback,
        bus: Bus,
        emulator: DeviceEmulator | None,
        stop: threading.Event,
        *,
        camera_tier: str = "pixel",
        robot_rate_hz: float = 200.0,
        tf_rate_hz: float = 30.0,
        loop: bool = True,
        status_period_s: float = 1.0,
        render_nice: int = 0,
    ):
        self.sim = sim
        self.bus = bus
        self.emulator = emulator
        self.stop = stop
        self.camera_tier = camera_tier
        self.loop = loop
        self.counters = LiveCounters()
        self.duration_ns = int(sim.gt.t_ns[-1]) + 1_000_000
        self._robot_period_ns = int(1e9 / robot_rate_hz)
        self._tf_period_ns = int(1e9 / tf_rate_hz)
        self._sched = _device_schedule(sim)
        self._robot_pub = bus.publisher("bench/robot")
        self._tf_pub = bus.publisher("bench/tf", reliable=False)
        self._info_pub = bus.publisher("camera/info")
        self._image_pub = bus.publisher("camera/image", reliable=False) if camera_tier == "pixel" else None
        self._vision_pub = bus.publisher("vision/observation") if camera_tier == "measurement" else None
        self._status_pub = bus.publisher("bench/status")
        self.status_period_s = status_period_s
        self.render_nice = render_nice
        n_frames = len(sim.camera_frames.t_true_ns) if camera_tier != "none" else 0
        self.camera_hz = n_frames / (self.duration_ns * 1e-9) if n_frames else 0.0
        self.meter = LoadMeter("bench", self.camera_hz)
        self._behind_said = False
        self._camera_ready = camera_tier == "none"
        self.t0_ns = 0

    # device and truth ------------------------------------------------------------
    def _send_device(self, kind: int, i: int, loop_offset_ns: int) -> None:
        s = self.sim.streams[_STREAMS[kind]]
        dev_us = (int(s.device_ns[i]) + loop_offset_ns) // 1000
        em = self.emulator
        assert em is not None
        if kind == GYRO:
            em.send_gyro(dev_us, s.values[i].tolist())
        elif kind == ACCEL:
            em.send_accel(dev_us, s.values[i].tolist())
        elif kind == MAG:
            em.send_mag(dev_us, s.values[i].tolist())
        else:
            em.send_tof(
                dev_us,
                float(s.values[i]),
                int(s.status[i]),
                float(s.extra["smoothed_mm"][i]),
                bool(s.extra["smoothed_valid"][i]),
            )
        self.counters.device_sent += 1

    def _robot_message(self, i: int, stamp_ns: int, seq: int) -> robot_pb2.RobotState:
        gt = self.sim.gt
        r = np.asarray(gt.rcm_base_m, float)
        R = gt.R_base_tool[i]
        p = gt.p_tip_base_m[i]
        u = R[:, 2]
        depth = float((p - r) @ u)
        m = robot_pb2.RobotState()
        m.header.stamp_ns, m.header.seq, m.header.frame_id = stamp_ns, seq, "base"
        m.q_rad.extend(gt.q_rad[i].tolist())
        m.dq_radps.extend(gt.dq_radps[i].tolist())
        m.tool_pose.position_m.x, m.tool_pose.position_m.y, m.tool_pose.position_m.z = p.tolist()
        q = rot_to_quat(R)
        o = m.tool_pose.orientation
        o.x, o.y, o.z, o.w = q.tolist()
        m.tip_m.x, m.tip_m.y, m.tip_m.z = p.tolist()
        m.rcm_m.x, m.rcm_m.y, m.rcm_m.z = r.tolist()
        m.depth_mm = depth * 1e3
        m.rcm_error_mm = float(np.linalg.norm((p - r) - depth * u) * 1e3)
        m.scenario = self.sim.scenario_name
        m.trial = int(gt.trial[i])
        m.phase = str(int(gt.phase[i]))
        return m

    def _tf_message(self, i: int, stamp_ns: int) -> FrameTransforms:
        gt = self.sim.gt
        msg = FrameTransforms()
        for parent, child, T in (
            ("base", "tool", None),
            ("base", "camera", self.sim.T_base_camera),
        ):
            tf = msg.transforms.add()
            tf.timestamp.FromNanoseconds(stamp_ns)
            tf.parent_frame_id, tf.child_frame_id = parent, child
            R, p = (gt.R_base_tool[i], gt.p_tip_base_m[i]) if T is None else (T[:3, :3], T[:3, 3])
            tf.translation.x, tf.translation.y, tf.translation.z = np.asarray(p, float).tolist()
            q = rot_to_quat(np.asarray(R, float))
            tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = q.tolist()
        return msg

    def _device_and_truth(self) -> None:
        t_dev, kind, idx = self._sched
        n_truth = len(self.sim.gt.t_ns)
        robot_seq = 0
        loop_k = 0
        while not self.stop.is_set():
            base = self.t0_ns + loop_k * self.duration_ns
            off = loop_k * self.duration_ns
            j = 0
            next_robot = 0
            next_tf = 0
            next_hello = 0
            while not self.stop.is_set():
                rel = now_ns() - base
                if rel >= self.duration_ns:
                    break
                # device samples due now (written at their simulated arrival time)
                if self.emulator is not None:
                    while j < len(t_dev) and t_dev[j] <= rel:
                        self._send_device(int(kind[j]), int(idx[j]), off)
                        j += 1
                    if rel >= next_hello:
                        self.emulator.send_hello((rel + off + self.sim.clock_offset_ns) // 1000)
                        next_hello += 1_000_000_000
                else:
                    j = int(np.searchsorted(t_dev, rel, side="right"))
                if rel >= next_robot:
                    i = min(n_truth - 1, rel // 1_000_000)
                    stamp = base + int(self.sim.gt.t_ns[i])
                    self._robot_pub.put(self._robot_message(int(i), stamp, robot_seq))
                    robot_seq += 1
                    self.counters.robot_published += 1
                    next_robot += self._robot_period_ns
                    if rel >= next_tf:
                        self._tf_pub.put(self._tf_message(int(i), stamp))
                        next_tf += self._tf_period_ns
                due = min(next_robot, t_dev[j] if j < len(t_dev) else next_robot)
                wait_s = (base + due - now_ns()) * 1e-9
                if wait_s > 0:
                    self.stop.wait(min(wait_s, 0.05))
            loop_k += 1
            self.counters.loops = loop_k
            if not self.loop:
                self.stop.set()

    # camera ---------------------------------------------------------------------
    def _camera(self) -> None:
        sim = self.sim
        cam = sim.camera
        frames = sim.camera_frames
        if self._image_pub is not None:
            # A cached pixel pass: the session and the renderer's first frame (its scene built)
            # at the normal priority, the start's critical path; the frames due meanwhile are
            # skipped as late and not judged (the meter's period starts after).
            sim.render_frame(0)
        self._camera_ready = True
        self.meter.status()
        lower_this_thread(self.render_nice, log)
        n = len(frames.t_true_ns)
        period_ns = int(1e9 / self.camera_hz) if self.camera_hz > 0 else 66_666_667
        render_ns = 0.0  # the expected render time: a frame is rendered ahead, to leave at its time
        loop_k = 0
        next_info = 0
        while not self.stop.is_set():
            base = self.t0_ns + loop_k * self.duration_ns
            for k in range(n):
                if self.stop.is_set():
                    return
                due = base + int(frames.publish_ns[k])
                wait_s = (due - render_ns - now_ns()) * 1e-9
                if wait_s > 0 and self.stop.wait(wait_s):
                    return
                # a frame that would leave more than two periods after its time is skipped: the
                # camera keeps real time, a slow renderer costs frames, not latency
                if now_ns() + render_ns - due > 2 * period_ns:
                    self.counters.frames_skipped_late += 1
                    self.meter.count("frames_skipped_late")
                    continue
                cap = base + int(frames.capture_ns[k])
                t_render = now_ns()
                payload, took = b"", 0
                pub = self._image_pub if self._image_pub is not None else self._vision_pub
                if self._image_pub is not None:
                    img = sim.render_frame(k)
                    payload = images.raw_image(img, cap, cam.frame_id).SerializeToString()
                    took = now_ns() - t_render
                    render_ns = took if render_ns == 0 else 0.8 * render_ns + 0.2 * took
                elif self._vision_pub is not None:
                    payload = self._vision_payload(k, base)
                wait_s = (due - now_ns()) * 1e-9  # rendered early: it leaves at its time, as a camera's
                if wait_s > 0 and self.stop.wait(wait_s):
                    return
                if now_ns() >= next_info:  # before the frame: vision needs the camera for its first
                    self._info_pub.put(cam.to_calibration(cap))
                    next_info = now_ns() + 1_000_000_000
                if pub is not None:
                    pub.put_bytes(payload)
                self.counters.frames_published += 1
                self.meter.count("frames_published")
                self.meter.done(took * 1e-6)
            loop_k += 1
            if not self.loop:
                return

    def _vision_payload(self, k: int, base: int) -> bytes:
        m = vision_pb2.VisionObservation.FromString(self.sim.vision_payloads[k])
        m.header.stamp_ns += base
        m.processed_stamp_ns += base
        return m.SerializeToString()

    # status ---------------------------------------------------------------------
    def publish_status(self) -> None:
        """bench/status for the period since the last call; one log line when the camera falls
        behind its rate, and one when it keeps it again."""
        if not self._camera_ready:  # loading the renderer: nothing to judge yet
            m = system_pb2.LoadStatus(service="bench", target_hz=self.camera_hz, note="loading the renderer")
            m.header.stamp_ns = now_ns()
            self._status_pub.put(m)
            return
        m = self.meter.status()
        if m.target_hz > 0:
            m.note = (
                f"{m.achieved_hz:.1f} of {m.target_hz:.0f} frames/s {'rendered' if self._image_pub else 'published'}"
                f" (render p95 {m.latency_p95_ms:.0f} ms)"
            )
            if m.behind:
                m.note = f"cannot keep {m.target_hz:.0f} frames/s: " + m.note + "; late frames are skipped"
            if m.behind != self._behind_said:
                self._behind_said = m.behind
                (log.warning if m.behind else log.info)("camera: %s", m.note if m.behind else "keeps its rate again")
        self._status_pub.put(m)

    # run ------------------------------------------------------------------------
    def run(self) -> None:
        self.t0_ns = now_ns() + 50_000_000
        threads = [threading.Thread(target=self._device_and_truth, name="bench-device", daemon=True)]
        if self.camera_tier != "none":
            threads.append(threading.Thread(target=self._camera, name="bench-camera", daemon=True))
        for t in threads:
            t.start()
        while not self.stop.wait(self.status_period_s):
            self.publish_status()
        for t in threads:
            t.join(timeout=1.0)


def prepare(scenario: Any, seed: int, camera_tier: str, duration_s: float | None) -> Any:
    """Simulate one pass of the scenario (a SimulatedSession) for live playback."""
    from services.bench.simulation import simulate_session

    t = time.perf_counter()
    tier = "pixel" if camera_tier == "pixel" else "measurement"
    sim = simulate_session(scenario, seed, tier, duration_s)
    log.info(
        "simulated %s (%.1f s of motion) in %.1f s", scenario.name, sim.gt.t_ns[-1] * 1e-9, time.perf_counter() - t
    )
    return sim
