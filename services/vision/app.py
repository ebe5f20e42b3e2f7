"""`python -m services.vision`: camera/image (+ camera/info) in, vision/observation and a
throttled vision/preview out.

The service always works on the newest frame: a frame that arrives while another is being
processed replaces the one waiting, and the replaced (stale) frame is dropped and counted rather
than queued, so the observations never fall behind the camera. A frame of the wrong size or
encoding, or one that does not decode, is rejected with its reason (an observation with
accepted = false says so) and counted; the service stays up. The observation's header carries
the frame's capture stamp unchanged, so a vision service on another machine (a client of the
cart's router: `--mode client -e tcp/CART:7447`) needs no clock synchronisation.

`workers` threads (default 2) each take the newest frame when free, so two frames are
processed side by side on two cores (torch and OpenCV release the GIL); observations are
published in the order their frames were taken (services.vision.overlap.InOrder). A frame waits
at most until a worker is free, so an observation leaves at most about two processing times
after its frame arrived, however loaded the machine. The workers run at a lower priority
(`worker_nice`) than fusion and the rest, so the network takes only the CPU they leave; loading
(torch, the checkpoint) keeps the normal priority, since the first estimate waits for it.

Every status period, vision/status (a LoadStatus) says the frames received, processed, accepted
and dropped as stale since start, the observations per second and the p95 latency from a frame's
arrival to its observation over the period.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections import Counter
from collections.abc import Sequence

from pydantic import Field

from services.vision import DEFAULT_WEIGHTS
from services.vision.overlap import InOrder
from services.vision.pipeline import PipelineParams
from tiplog.clock import now_ns
from tiplog.config import ServiceConfig
from tiplog.loadstatus import LoadMeter
from tiplog.priority import lower_this_thread
from tiplog.service import ServiceContext, run_service

NAME = "vision"


class VisionConfig(ServiceConfig):
    """Configuration of the vision service (section `vision:` of the YAML file)."""

    weights: str = Field("", description="network checkpoint; empty: the one shipped in models/")
    device: str = Field("auto", pattern=r"^(auto|cpu|cuda(:\d+)?)$")
    torch_threads: int = Field(
        0, ge=0, le=64, description="CPU threads for each worker's network (0: the cores there are over the workers)"
    )
    calibration: str = Field("", description="calibration YAML giving the shaft radius; empty: shaft_radius_m")
    shaft_radius_m: float = Field(0.00259, gt=0.0005, lt=0.01)
    pipeline: PipelineParams = Field(default_factory=PipelineParams)
    preview_hz: float = Field(3.0, ge=0.0, le=15.0, description="vision/preview at most this often (0: off)")
    preview_width_px: int = Field(320, ge=64, le=1280)
    workers: int = Field(
        2, ge=1, le=8, description="frames processed side by side (each worker takes the newest frame when free)"
    )
    worker_nice: int = Field(10, ge=0, le=19, description="nice increment of the workers: the network yields")


class NewestFrame:
    """A one-place mailbox: `put` replaces what waits (counting it as dropped), `take` empties it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._item: object | None = None
        self._event = threading.Event()
        self.received = 0
        self.dropped_stale = 0

    def put(self, item: object) -> None:
        with self._lock:
            self.received += 1
            if self._item is not None:
                self.dropped_stale += 1
            self._item = item
            self._event.set()

    def take(self, timeout_s: float) -> object | None:
        if not self._event.wait(timeout_s):
            return None
        with self._lock:
            item, self._item = self._item, None
            self._event.clear()
        return item


def cores() -> int:
    """The cores this process may run on (its affinity, which a container's cpuset narrows)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def torch_threads(cfg: VisionConfig) -> int:
    """Threads for the network: as configured, else the cores shared out over the workers (the
    workers already run side by side; more threads than cores only make them wait on each other)."""
    return cfg.torch_threads or max(1, cores() // cfg.workers)


def _load(cfg: VisionConfig, log):
    """(Pipeline, shaft radius) from the configuration; SystemExit(2) with one log line on error."""
    import torch

    from services.vision.network import load_checkpoint
    from services.vision.pipeline import Pipeline
    from tiplog.calibration import Calibration, CalibrationError

    torch.set_num_threads(torch_threads(cfg))
    rho = cfg.shaft_radius_m
    try:
        if cfg.calibration:
            rho = Calibration.load_yaml(cfg.calibration).shaft_radius_m
        seg, extra = load_checkpoint(cfg.weights or DEFAULT_WEIGHTS, cfg.device)
    except (CalibrationError, ValueError) as e:
        log.error("%s", e)
        raise SystemExit(2) from None
    log.info(
        "network on %s (%s), %d worker(s) of %d thread(s) on %d core(s), nice +%d; shaft radius %.3f mm",
        seg.device, cfg.weights or DEFAULT_WEIGHTS, cfg.workers, torch.get_num_threads(), cores(), cfg.worker_nice,
        rho * 1e3,
    )  # fmt: skip
    return Pipeline(seg, rho, cfg.pipeline)


def _load_or_error(cfg: VisionConfig, log):
    try:
        return _load(cfg, log)
    except SystemExit as e:
        return e


def body(ctx: ServiceContext[VisionConfig]) -> None:
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    from services.vision.frames import FrameError, decode_frame
    from services.vision.preview import preview_message
    from tiplog.geometry.camera import CameraModel
    from tiplog.v1 import vision_pb2

    cfg, log = ctx.config, ctx.log
    # torch and the checkpoint take seconds to load: on a thread, so a signal meanwhile still
    # stops the service at once
    loaded: list = []
    loader = threading.Thread(target=lambda: loaded.append(_load_or_error(cfg, log)), name="load", daemon=True)
    loader.start()
    while not loaded:
        if ctx.stop.wait(0.05):
            log.info("stopped while loading the network")
            _abandoned.append(loader)
            return
    if isinstance(loaded[0], SystemExit):
        raise loaded[0]
    pipeline = loaded[0]
    camera: list[CameraModel] = []
    rejected: Counter[str] = Counter()
    # frames that came before any camera/info (the service starting ahead of the camera) are not
    # bad frames: counted apart, so that a status line's "bad frames" means the camera's fault
    counts = {"processed": 0, "accepted": 0, "bad_frames": 0, "early": 0}

    def on_info(msg, _info) -> None:
        try:
            cam = CameraModel.from_calibration(msg)
        except ValueError as e:
            rejected["bad_camera_info"] += 1
            log.warning("camera/info rejected: %s", e)
            return
        if not camera or camera[0] != cam:
            log.info("camera %dx%d fx=%.1f", cam.width, cam.height, cam.fx)
            camera[:] = [cam]

    slot = NewestFrame()
    meter = LoadMeter(NAME, 0.0)  # the target: the camera's rate, as received
    meter.status()  # the first period starts now
    pub_obs = ctx.bus.publisher("vision/observation")
    pub_status = ctx.bus.publisher("vision/status")
    pub_prev = ctx.bus.publisher("vision/preview", reliable=False)
    ctx.bus.subscribe("camera/info", on_info)
    sub_img = ctx.bus.subscribe("camera/image", lambda m, i: slot.put((m, i, time.monotonic())), msg_type=RawImage)
    next_status = time.monotonic() + cfg.status_period_s

    def status() -> None:
        log.info(
            "frames %d, processed %d, accepted %d, dropped stale %d, before camera/info %d, bad frames %d, "
            "undecodable %d, reasons %s",
            slot.received, counts["processed"], counts["accepted"], slot.dropped_stale, counts["early"], counts["bad_frames"],
            sub_img.decode_errors, dict(rejected) or "none",
        )  # fmt: skip

    received_at_last = [0]

    def publish_status() -> None:
        with lock:
            meter.counts.update(
                frames_received=slot.received, frames_processed=counts["processed"], frames_accepted=counts["accepted"],
                frames_dropped_stale=slot.dropped_stale, frames_before_camera_info=counts["early"],
                frames_bad=counts["bad_frames"],
            )  # fmt: skip
        received, received_at_last[0] = slot.received - received_at_last[0], slot.received
        meter.target_hz = received / cfg.status_period_s  # what the camera sent
        m = meter.status()
        m.note = f"{m.achieved_hz:.1f} of {m.target_hz:.1f} frames/s processed, the rest dropped as stale"
        pub_status.put(m)

    lock = threading.Lock()  # counts and the preview's clock, shared by the workers
    order = InOrder()
    last_preview = [0.0]

    def handle(item, ticket: int) -> None:  # noqa: ANN001  (msg, info, arrival) from the slot
        msg, info, arrived = item
        stamp = msg.timestamp.ToNanoseconds()
        try:
            try:
                if not camera:
                    raise FrameError("no_camera_info", "no camera/info received yet")
                cam = camera[0]
                frame = decode_frame(msg, cam)
            except FrameError as e:
                with lock:
                    rejected[e.reason] += 1
                    counts["early" if e.reason == "no_camera_info" else "bad_frames"] += 1
                    n = rejected[e.reason]
                if n <= 5 or n % 100 == 0:
                    log.warning("frame at %d rejected (%d so far): %s", stamp, n, e)
                obs = vision_pb2.VisionObservation(accepted=False, reject_reason=f"frame:{e.reason}")
                obs.header.stamp_ns = stamp
                obs.header.frame_id = msg.frame_id
                obs.header.seq = info.seq
                obs.processed_stamp_ns = now_ns()
                order.wait_turn(ticket)
                pub_obs.put(obs)
                return
            res = pipeline.process(frame, cam, stamp, info.seq)
            res.obs.processed_stamp_ns = now_ns()
            order.wait_turn(ticket)  # observations leave in the order their frames were taken
            pub_obs.put(res.obs)
            now = time.monotonic()
            meter.done((now - arrived) * 1e3)
            with lock:
                counts["processed"] += 1
                counts["accepted"] += int(res.obs.accepted)
                if not res.obs.accepted:
                    rejected[res.obs.reject_reason] += 1
                preview = cfg.preview_hz > 0 and now - last_preview[0] >= 1.0 / cfg.preview_hz
                if preview:
                    last_preview[0] = now
            if preview:
                pub_prev.put(preview_message(frame, res, cam, cfg.preview_width_px))
        finally:
            order.done(ticket)

    taking = threading.Lock()  # a frame and its ticket are taken together: tickets follow the frames

    def work() -> None:
        lower_this_thread(cfg.worker_nice, log)
        while not ctx.stop.is_set():
            with taking:
                item = slot.take(0.1)
                ticket = order.ticket() if item is not None else -1
            if item is None:
                continue
            try:
                handle(item, ticket)
            except Exception:  # a bug on one frame must not stop the worker
                log.exception("processing a frame failed")

    workers = [threading.Thread(target=work, name=f"vision-{k}", daemon=True) for k in range(cfg.workers)]
    for w in workers:
        w.start()
    while not ctx.stop.wait(0.1):
        if time.monotonic() >= next_status:
            next_status += cfg.status_period_s
            status()
            publish_status()
    for w in workers:
        w.join(5.0)
    status()
    publish_status()


# A loader thread still inside torch's import or checkpoint load when the service stops. It
# cannot be cancelled, and letting the interpreter finalise around it aborts the process from
# C++ ("terminate called without an active exception"): `main` ends the process without
# finalising instead, once the bus is closed and the logs are flushed.
_abandoned: list[threading.Thread] = []


def main(argv: Sequence[str] | None = None) -> int:
    try:
        rc = run_service(NAME, VisionConfig, body, argv, description=__doc__)
    except SystemExit as e:
        rc = int(e.code or 0)
    if any(t.is_alive() for t in _abandoned):
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    return rc
