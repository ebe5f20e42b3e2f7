"""`python -m services.bench`: the simulated bench live. The chosen scenario is played in real
time: device bytes through a pseudo-terminal in the device's serial protocol (the gateway
reads it as it would the real module), camera frames or vision observations and the robot's
ground truth on the bus."""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

from pydantic import Field

from tiplog.config import ConfigError, ServiceConfig
from tiplog.service import ServiceContext, run_service

NAME = "bench"


class BenchConfig(ServiceConfig):
    """Configuration of the bench service (section `bench:` of the YAML file)."""

    scenario: str = "demo"  # built-in name or YAML file
    scenario_overrides: list[str] = Field(default_factory=list)  # "field.path=value"
    seed: int = Field(0, ge=0)
    duration_s: float | None = Field(None, gt=0.0, le=3600.0)  # one pass; default: the scenario's
    loop: bool = True
    # Where the emulated device's pseudo-terminal appears (the gateway's `port`); "" = no device.
    device_link: str = "/tmp/tiplog-device"
    camera_tier: Literal["pixel", "measurement", "none"] = "pixel"
    robot_rate_hz: float = Field(200.0, gt=0.0, le=1000.0)
    tf_rate_hz: float = Field(30.0, gt=0.0, le=200.0)
    # Where the as-calibrated constants are written at start-up (tiplog.calibration format, the
    # same record as a session's `calibration_as_calibrated`); "" = not written.
    calibration_file: str = ""
    # Simulated passes kept for the next start with the same scenario, seed and sources (a
    # restart plays at once instead of simulating for seconds); "" = none kept.
    pass_cache_dir: str = Field(default_factory=lambda: os.path.join(_cache_home(), "tiplog", "bench"))
    # The camera's renderer yields to the device stream and to the other services (nice
    # increment of its thread; 0 = as the process): a busy machine costs frames, said on bench/status.
    render_nice: int = Field(10, ge=0, le=19)


def _cache_home() -> str:
    return os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")


def _cached_pass(cfg: BenchConfig) -> Path | None:
    """Where this configuration's pass is cached (whether or not it is there yet); None when
    the cache is off."""
    if not cfg.pass_cache_dir:
        return None
    from services.bench import playback

    key = playback.cache_key(cfg.scenario, cfg.scenario_overrides, cfg.seed, cfg.duration_s, cfg.camera_tier)
    return playback.cache_path(cfg.pass_cache_dir, key)


def write_calibration(cfg: BenchConfig, text: str | None = None) -> Path | None:
    """Write the as-calibrated constants of (scenario, seed) to `cfg.calibration_file` (or
    `text`, that file as a cached pass holds it), under a temporary name renamed when complete
    (a reader never sees half a file); None when unset."""
    if not cfg.calibration_file:
        return None
    final = Path(cfg.calibration_file)
    if not final.parent.is_dir():
        raise ConfigError(f"config error: calibration_file: folder {final.parent} does not exist")
    tmp = final.with_name(f".{final.name}.{os.getpid()}.partial")
    try:
        if text is not None:
            tmp.write_text(text)
        else:
            from services.bench.scenario import load_scenario
            from services.bench.simulation import as_calibrated_constants
            from tiplog.calibration import Calibration

            scenario = load_scenario(cfg.scenario, cfg.scenario_overrides)
            calib = Calibration.from_dict(as_calibrated_constants(scenario, cfg.seed).to_dict(), where="bench")
            calib.save_yaml(tmp, extra={"source": f"bench scenario {scenario.name}, seed {cfg.seed}, as calibrated"})
        os.replace(tmp, final)
    finally:
        tmp.unlink(missing_ok=True)
    return final


def check_duration(cfg: BenchConfig) -> None:
    """ConfigError when one pass (duration_s, else the scenario's) holds no sample of some
    device stream: the simulation cannot play it (an empty stream was a traceback after the
    bus had opened). The rule and the words of `tiplog sim generate`. A configuration whose pass
    is cached passed it when the pass was simulated."""
    cached = _cached_pass(cfg)
    if cached is not None and cached.is_file():
        return
    from services.bench.scenario import load_scenario
    from services.bench.simulation import duration_problem

    scenario = load_scenario(cfg.scenario, cfg.scenario_overrides)
    what = "duration_s" if cfg.duration_s is not None else f"the scenario's duration_s ({cfg.scenario})"
    problem = duration_problem(scenario, cfg.duration_s if cfg.duration_s is not None else scenario.duration_s, what)
    if problem:
        raise ConfigError(f"config error: {problem}")


def _prepare(cfg: BenchConfig, log: logging.Logger):
    """The pass to play, with the calibration file written: from the pass cache when it holds
    this configuration's, else simulated (imports Pinocchio and the models: seconds) and cached."""
    from services.bench import playback

    cached = _cached_pass(cfg)
    play = playback.load(cached) if cached is not None else None
    if play is not None:
        path = write_calibration(cfg, play.calibration_yaml)
        log.info("pass loaded from %s", cached)
    else:
        from services.bench.live import prepare
        from services.bench.scenario import load_scenario

        path = write_calibration(cfg)
        sim = prepare(load_scenario(cfg.scenario, cfg.scenario_overrides), cfg.seed, cfg.camera_tier, cfg.duration_s)
        play = playback.Playback.from_session(sim, path.read_text() if path is not None else None)
        if cached is not None:
            playback.store(cached, play)
    if path is not None:
        log.info("as-calibrated constants written to %s", path)
    return play


def body(ctx: ServiceContext[BenchConfig]) -> None:
    cfg = ctx.config
    # Imports and simulation take seconds: a daemon thread does them so that a signal still
    # stops the service at once (the thread is abandoned with the process).
    result: list = []
    ready = threading.Event()

    def work() -> None:
        try:
            result.append(_prepare(cfg, ctx.log))
        except Exception as e:  # reported on the main thread
            result.append(e)
        finally:
            ready.set()

    threading.Thread(target=work, name="bench-prepare", daemon=True).start()
    while not ready.wait(0.1):
        if ctx.stop.is_set():
            return
    if isinstance(result[0], ConfigError):
        ctx.log.error("%s", result[0])
        raise SystemExit(2)
    if isinstance(result[0], Exception):
        raise result[0]
    sim = result[0]

    from services.bench.live import LiveBench
    from tiplog.devproto.emulator import DeviceEmulator

    emulator = None
    if cfg.device_link:
        emulator = DeviceEmulator(cfg.device_link, rates_hz=sim.device_rates_hz, drop_without_host=True)
        emulator.plug()
        ctx.log.info("device on %s", cfg.device_link)
    try:
        live = LiveBench(
            sim,
            ctx.bus,
            emulator,
            ctx.stop,
            camera_tier=cfg.camera_tier,
            robot_rate_hz=cfg.robot_rate_hz,
            tf_rate_hz=cfg.tf_rate_hz,
            loop=cfg.loop,
            status_period_s=cfg.status_period_s,
            render_nice=cfg.render_nice,
        )
        live.run()
        ctx.log.info("played: %s", live.counters)
    finally:
        if emulator is not None:
            emulator.close()


def main(argv: Sequence[str] | None = None) -> int:
    return run_service(NAME, BenchConfig, body, argv, description=__doc__, check=check_duration)
