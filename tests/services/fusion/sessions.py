"""Short bench sessions shared by the fusion-core tests (generated once per test run)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from google.protobuf.message import Message

from tests.helpers.run_once import run_once
from tiplog.calibration import Calibration
from tiplog.cli import main as tiplog_main
from tiplog.geometry import quat_to_rot
from tiplog.mcap_io import McapWriter, read_messages, read_metadata


def bench_session(
    tmp_path_factory, scenario: str = "teleop", seed: int = 11, duration_s: float = 9.0, profile: str | None = None
) -> Path:
    """A bench session, generated once per test run (by one worker when the run is parallel);
    `profile` overrides the scenario's bench profile (the default is the paper's conditions)."""

    def generate(path: Path) -> None:
        args = ["sim", "generate", "--scenario", scenario, "--seed", str(seed), "--duration", str(duration_s)]
        if profile is not None:
            args += ["--set", f"profile={profile}"]
        assert tiplog_main([*args, "--out", str(path), "--quiet"]) == 0

    return run_once(tmp_path_factory, f"{scenario}_{seed}_{duration_s:g}s_{profile or 'default'}.mcap", generate)


def bench_geometry(tmp_path_factory) -> tuple[Calibration, np.ndarray]:
    """A bench calibration (as calibrated) and a plausible R_base_tool, from a 3 s session."""
    path = bench_session(tmp_path_factory, "translation", seed=41, duration_s=3.0)
    calib = Calibration.from_mcap_metadata(read_metadata(path))
    o = next(iter(read_messages(path, ["bench/robot"]))).message.tool_pose.orientation
    return calib, quat_to_rot(np.array([o.x, o.y, o.z, o.w]))


def bench_estimate(tmp_path_factory, session: Path) -> Path:
    """`tiplog fusion run` on `session` (a `bench_session`) with the built-in parameters, once per
    test run (read only)."""

    def run(out: Path) -> None:
        assert tiplog_main(["fusion", "run", str(session), "--out", str(out), "--quiet"]) == 0

    tag = hashlib.sha1(str(session).encode()).hexdigest()[:10]
    return run_once(tmp_path_factory, f"est_{session.stem}_{tag}.mcap", run)


def inputs(path: Path) -> list[tuple[str, Message, int]]:
    """(topic, message, arrival) of the filter's inputs in arrival order."""
    want = ("device/gyro", "device/accel", "device/tof", "vision/observation", "camera/info")
    return [(r.topic, r.message, r.log_time_ns) for r in read_messages(path, want)]


def rewrite(src: Path, dst: Path, keep_topic, keep_metadata) -> None:
    """Copy src to dst keeping only the topics and metadata records the predicates accept."""
    with McapWriter(dst) as w:
        for name, rec in read_metadata(src).items():
            if keep_metadata(name):
                w.add_metadata(name, rec)
        for r in read_messages(src):
            if keep_topic(r.topic):
                w.write(r.topic, r.message, r.log_time_ns, r.publish_time_ns, r.sequence)


# A 6 s sweeps session and its estimate with the built-in parameters, as the fixtures `session`
# and `estimate` (read only) of the modules that import these two functions.
@pytest.fixture(scope="module", name="session")
def sweeps_session_fixture(tmp_path_factory) -> Path:
    return bench_session(tmp_path_factory, "sweeps", seed=12, duration_s=6.0)


@pytest.fixture(scope="module", name="estimate")
def sweeps_estimate_fixture(session, tmp_path_factory) -> Path:
    return bench_estimate(tmp_path_factory, session)
