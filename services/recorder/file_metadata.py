"""What every recording file starts with: the session record (names, clocks, host, software),
the resolved configuration, the extra metadata and attachments given at start-up, and the
calibration file (attached as is; a tiplog calibration also as readable constants)."""

from __future__ import annotations

import json
import logging
import socket
from pathlib import Path
from typing import Any

import yaml

from services.recorder.config import RecorderConfig
from services.recorder.mcap_file import RecordingFile
from tiplog import __version__
from tiplog.calibration import Calibration, CalibrationError
from tiplog.clock import now_ns, wall_ns
from tiplog.config import dump

log = logging.getLogger("services.recorder.recorder")


def write_header_metadata(
    f: RecordingFile,
    cfg: RecorderConfig,
    session: dict[str, Any],
    extra_metadata: dict[str, dict[str, Any]],
    extra_attachments: dict[str, tuple[bytes, str]],
) -> None:
    """Session, configuration, extras and calibration into a freshly opened file."""
    f.add_metadata(
        "session",
        {
            **session,
            "software_version": __version__,
            "host": socket.gethostname(),
            "wall_start_ns": wall_ns(),
            "clock_start_ns": now_ns(),
            "log_time": "receive time on the recording host, CLOCK_MONOTONIC ns",
            "publish_time": "publisher's CLOCK_MONOTONIC ns at put",
            "sequence": "publisher's bus sequence number (low 32 bits)",
        },
    )
    f.add_metadata("configuration", {"recorder": dump(cfg)})
    for name, data in extra_metadata.items():
        f.add_metadata(name, data)
    for name, (blob, media_type) in extra_attachments.items():
        f.add_attachment(name, blob, media_type, now_ns())
    if cfg.calibration_file:
        p = Path(cfg.calibration_file)
        try:
            data = p.read_bytes()
            media = "application/yaml" if p.suffix in (".yaml", ".yml") else "application/octet-stream"
            f.add_attachment(p.name, data, media, now_ns())
            f.add_metadata("calibration", calibration_record(p, data))
        except OSError as e:
            log.warning("calibration file %s unreadable: %s", p, e)
            f.add_metadata("calibration", {"file": str(p), "error": str(e)})


def calibration_record(path: Path, data: bytes) -> dict[str, str | int]:
    """The `calibration` metadata record: the file's name and size, and for a tiplog calibration
    file its constants as JSON (what `Calibration.from_mcap_metadata` reads offline)."""
    rec: dict[str, str | int] = {"file": str(path), "size": len(data)}
    try:
        doc = yaml.safe_load(data)
        if isinstance(doc, dict) and "calibration" in doc:
            rec["json"] = json.dumps(Calibration.from_dict(doc["calibration"], where=str(path)).to_dict())
        else:
            rec["note"] = "not a tiplog calibration file: attached as is"
    except (yaml.YAMLError, CalibrationError) as e:
        rec["note"] = f"not a usable tiplog calibration file ({str(e).splitlines()[0]}): attached as is"
    return rec
