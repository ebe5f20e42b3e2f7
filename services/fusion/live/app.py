"""`python -m services.fusion`: the tracking filter live on the bus.

Subscribes device/gyro, device/accel, device/tof, vision/observation and camera/info;
publishes fusion/state (every gyro sample, a fixed delay behind real time), fusion/state_settled
(the same states once every late measurement is applied at its time, 1 s behind, for
archives), fusion/predicted (the newest state carried forward to the present, for display), fusion/tf (the estimated
tool pose as Foxglove FrameTransforms) and fusion/diagnostics (1-10 Hz). The calibration
comes from a calibration file (`calibration_file`, the `tiplog calibrate` format; `tiplog up`
passes the bench's as-calibrated file); without one the service says so and exits 2.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from services.fusion.config import FusionConfig
from services.fusion.eskf.params import Params, mode_name, parse_sensors
from services.fusion.live.service import LiveFusion, warm_kernels
from services.fusion.live.warmup import kernel_cache
from services.fusion.params_file import load_params
from tiplog.calibration import Calibration
from tiplog.service import ServiceContext, run_service

NAME = "fusion"


def _inputs(cfg: FusionConfig) -> tuple[Calibration, Params, frozenset[str]]:
    calibration = Calibration.load_yaml(cfg.calibration_file)
    params = load_params(cfg.params_file) if cfg.params_file else Params()
    return calibration, params, parse_sensors(cfg.sensors)


_prepared: list[bool] = []


def prepare(cfg: FusionConfig, wait_s: float = 300.0) -> None:
    """A spare's preparation under `tiplog up`: the compiled kernels loaded before it is called up.
    With no compiled cache yet, the running fusion is compiling them: the spare waits for its cache
    (up to `wait_s`) rather than compiling the same kernels beside it on the same cores."""
    deadline = time.monotonic() + wait_s
    while kernel_cache()[0] is False and time.monotonic() < deadline:
        time.sleep(1.0)  # polling a folder another process writes; nothing to wait on
    warm_kernels(*_inputs(cfg))
    _prepared.append(True)


def body(ctx: ServiceContext[FusionConfig]) -> None:
    cfg = ctx.config
    calibration, params, sensors = _inputs(cfg)
    live = LiveFusion(
        ctx.bus,
        calibration,
        params,
        sensors,
        diagnostics_hz=cfg.diagnostics_hz,
        prediction_hz=cfg.prediction_hz,
        tf_every=cfg.tf_every,
        queue_size=cfg.queue_size,
        input_log_file=cfg.input_log_file,
        warm=not _prepared,
    )
    ctx.log.info(
        "calibration %s, mode %s, output %.0f ms behind real time, settled %.0f ms behind",
        cfg.calibration_file,
        mode_name(sensors),
        params.output_delay_ms,
        params.max_age_ms,
    )
    live.start(ctx.stop)
    ctx.log.info("published %d states (%d settled) from %d inputs", live.published, live.settled, live.inputs)


def main(argv: Sequence[str] | None = None) -> int:
    return run_service(NAME, FusionConfig, body, argv, description=__doc__, prepare=prepare)
