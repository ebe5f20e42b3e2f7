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

from pydantic import Field, field_validator, model_validator

from services.fusion.eskf.params import Params, ParamsError, mode_name, parse_sensors
from services.fusion.live.service import LiveFusion, warm_kernels
from services.fusion.live.warmup import kernel_cache
from tiplog.calibration import Calibration, CalibrationError
from tiplog.config import ServiceConfig
from tiplog.service import ServiceContext, run_service

NAME = "fusion"


class FusionConfig(ServiceConfig):
    """Configuration of the fusion service (section `fusion:` of the YAML file)."""

    # Required: the filter never runs blind. A tiplog calibration YAML file.
    calibration_file: str | None = None
    params_file: str | None = None  # filter parameters (YAML); default: the built-in set
    sensors: str = "imu,tof,vision"  # any subset, for ablations
    diagnostics_hz: float = Field(2.0, ge=1.0, le=10.0)
    prediction_hz: float = Field(30.0, ge=0.0, le=200.0)  # 0: no fusion/predicted
    tf_every: int = Field(1, ge=1, le=1000)  # fusion/tf for every n-th published state
    queue_size: int = Field(100_000, ge=100, le=10_000_000)
    # Write every input as fed to the filter, with the arrival stamp it used, to this MCAP
    # file: `tiplog fusion run` on it reproduces the live trajectory exactly.
    input_log_file: str | None = None

    @model_validator(mode="after")
    def _calibration_given(self) -> FusionConfig:
        # After the fields, so that another bad value still gets its one line alone.
        if not self.calibration_file:
            raise ValueError(
                "calibration_file: fusion has no calibration: give a calibration file (tiplog calibrate "
                "writes one; `tiplog up` passes the bench's), e.g. --set calibration_file=calibration.yaml"
            )
        return self

    @field_validator("calibration_file")
    @classmethod
    def _calibration_loads(cls, v: str | None) -> str | None:
        if not v:
            return v
        try:
            Calibration.load_yaml(v)
        except CalibrationError as e:
            raise ValueError(str(e)) from None
        return v

    @field_validator("params_file")
    @classmethod
    def _params_load(cls, v: str | None) -> str | None:
        if v:
            try:
                Params.load_yaml(v)
            except ParamsError as e:
                raise ValueError(str(e)) from None
        return v

    @field_validator("sensors")
    @classmethod
    def _sensors_known(cls, v: str) -> str:
        try:
            parse_sensors(v)
        except ParamsError as e:
            raise ValueError(str(e).replace("--sensors: ", "")) from None
        return v


def _inputs(cfg: FusionConfig) -> tuple[Calibration, Params, frozenset[str]]:
    calibration = Calibration.load_yaml(cfg.calibration_file)
    params = Params.load_yaml(cfg.params_file) if cfg.params_file else Params()
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
