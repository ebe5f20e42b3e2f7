"""The fusion service's configuration (section `fusion:` of the YAML file), where `tiplog up`
looks for it: checked before anything starts, without importing the service."""

from __future__ import annotations

from pydantic import Field, field_validator, model_validator

from services.fusion.eskf.params import ParamsError, parse_sensors
from services.fusion.params_file import load_params
from tiplog.calibration import Calibration, CalibrationError
from tiplog.config import ServiceConfig


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
                load_params(v)
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
