"""Configuration of the recorder (section `recorder:` of the YAML file)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from tiplog.config import ServiceConfig

MiB = 1024 * 1024
GiB = 1024 * MiB


class RecorderConfig(ServiceConfig):
    """Where and how the recorder writes. Sizes in bytes, periods in seconds."""

    out_dir: str = "recordings"
    # never: only on command; device: when device/status reports STREAMING; always: at launch.
    autostart: Literal["never", "device", "always"] = "device"
    # Key expression under the bus prefix that is recorded.
    key_expr: str = "**"
    # Topics left out ("camera/image"; "camera/" leaves out every camera/* topic): the demo
    # records everything but the raw frames (41 MB/s), whose compressed preview is kept.
    exclude_topics: list[str] = Field(default_factory=list)
    # Camera frames (foxglove.RawImage on `camera_topics`) archived as JPEG
    # foxglove.CompressedImage on `<topic>/compressed` (services/recorder/camera_archive.py), or
    # as they come ("raw": several hundred GB per hour at 30 frames/s).
    camera_archive: Literal["jpeg", "raw"] = "jpeg"
    camera_topics: list[str] = Field(default_factory=lambda: ["camera/image"])
    camera_jpeg_quality: int = Field(90, ge=1, le=100)
    # lz4 by default: camera frames are noise-like and dominate the volume; zstd costs several
    # times the CPU for little gain on them (see benchmarks/recorder_throughput.py).
    compression: Literal["zstd", "lz4", "none"] = "lz4"
    chunk_size_bytes: int = Field(4 * MiB, ge=64 * 1024, le=256 * MiB)
    # A chunk is closed and flushed to the OS at least this often: kill -9 loses at most this.
    flush_period_s: float = Field(0.5, gt=0.0, le=1.0)
    # fsync the file this often against power loss (0: never, the OS decides).
    fsync_period_s: float = Field(2.0, ge=0.0, le=3600.0)
    # Split into a new file when the current one reaches either limit (0: no limit).
    max_file_bytes: int = Field(4 * GiB, ge=0)
    max_file_duration_s: float = Field(900.0, ge=0.0)
    # Refuse to start, and stop, when free space on the target falls below this.
    min_free_bytes: int = Field(2 * GiB, ge=0)
    # Alarm (recording goes on) when the free space above that reserve holds fewer minutes of
    # case than this at the current write rate; the alarm says how many.
    warn_minutes_left: float = Field(30.0, ge=0.0)
    disk_check_period_s: float = Field(1.0, gt=0.0, le=60.0)
    # Bound on what waits for the writer thread; beyond it messages are dropped and counted.
    max_queue_bytes: int = Field(512 * MiB, ge=1 * MiB)
    max_queue_messages: int = Field(200_000, ge=100)
    # Recorded as an attachment and metadata in every file when given.
    calibration_file: str | None = None
    # Payloads that are not a well-formed message of their topic's type (see
    # services/recorder/admission.py) never enter the topic's channel; they are counted and,
    # unless `quarantine` is off, kept on `_rejected/<topic>:<reason>` up to these sizes
    # (larger ones, and those beyond the per-file budget, are counted as dropped there).
    quarantine: bool = True
    quarantine_max_payload_bytes: int = Field(8 * MiB, ge=0)
    quarantine_max_bytes_per_file: int = Field(64 * MiB, ge=0)
    # Session name prefix; a session is `<prefix><UTC start time>` unless named on START.
    session_prefix: str = "tiplog_"
