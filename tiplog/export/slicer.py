"""PLUS / 3D Slicer sequence file (MetaIO `.seq.mha`): the tracked tool as transforms per frame.

The file is a MetaIO image of 1 x 1 x N pixels (zeros: there is no image; each frame's
`ImageStatus` says INVALID) whose header holds, for each frame k, as PLUS writes them:
`Seq_FrameKKKK_<From>To<To>Transform` (16 numbers, row-major 4x4, millimetres),
`Seq_FrameKKKK_<From>To<To>TransformStatus` (OK or INVALID), `Seq_FrameKKKK_Timestamp`
(seconds since the first frame) and `Seq_FrameKKKK_FrameNumber`; tiplog adds
`Seq_FrameKKKK_StampNs` (the state's own host-clock stamp, int64 ns). The transforms are
those of the live OpenIGTLink service: TipToReference (the tip, identity rotation),
ToolToReference (the shaft frame at the tip) and, with a calibration, TrocarToReference.
Slicer's Sequences module loads the file as a sequence browser with one transform node each.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tiplog.export.track import Frames, Track
from tiplog.userio import UserError

TIP, TOOL, TROCAR = "TipToReference", "ToolToReference", "TrocarToReference"


def frame_matrices_mm(track: Track, row: int) -> dict[str, np.ndarray]:
    """T_reference_tip and T_reference_tool [mm] of one track row."""
    tip = np.eye(4)
    tip[:3, 3] = track.p_tip_base_m[row] * 1e3
    tool = tip.copy()
    tool[:3, :3] = track.R_base_tool[row]
    return {TIP: tip, TOOL: tool}


def _numbers(m: np.ndarray) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(m))


def write_sequence(
    path: Path,
    track: Track,
    segments: Sequence[Frames],
    rcm_base_m: np.ndarray | None,
    provenance: dict[str, str],
) -> int:
    """Write every segment's frames one after another (time continues across segments, a
    `Seq_FrameKKKK_Segment` field says which); returns the frame count."""
    lines: list[str] = []
    k = 0
    t_offset = 0.0
    for seg in segments:
        for t, row, ok in zip(seg.time_s, seg.index, seg.valid, strict=True):
            f = f"Seq_Frame{k:04d}_"
            mats = frame_matrices_mm(track, int(row)) if ok else {TIP: np.eye(4), TOOL: np.eye(4)}
            if rcm_base_m is not None:
                troc = np.eye(4)
                troc[:3, 3] = np.asarray(rcm_base_m, float) * 1e3
                mats[TROCAR] = troc if ok else np.eye(4)
            lines.append(f"{f}FrameNumber = {k}")
            for name, m in mats.items():
                lines.append(f"{f}{name}Transform = {_numbers(m)}")
                lines.append(f"{f}{name}TransformStatus = {'OK' if ok else 'INVALID'}")
            lines.append(f"{f}Timestamp = {t_offset + float(t):.6f}")
            lines.append(f"{f}StampNs = {int(track.t_ns[row]) if ok else 0}")
            lines.append(f"{f}Segment = {seg.segment}")
            lines.append(f"{f}ImageStatus = INVALID")
            k += 1
        t_offset += float(seg.time_s[-1]) + (float(seg.time_s[1] - seg.time_s[0]) if len(seg.time_s) > 1 else 0.0)
    if k == 0:
        raise UserError("nothing to export: no segment holds two fusion states")
    head = [
        "ObjectType = Image",
        "NDims = 3",
        "AnatomicalOrientation = RAI",
        "BinaryData = True",
        "BinaryDataByteOrderMSB = False",
        "CenterOfRotation = 0 0 0",
        "CompressedData = False",
        f"DimSize = 1 1 {k}",
        "ElementNumberOfChannels = 1",
        "ElementSpacing = 1 1 1",
        "ElementType = MET_UCHAR",
        "Offset = 0 0 0",
        "TransformMatrix = 1 0 0 0 1 0 0 0 1",
        "UltrasoundImageOrientation = MFA",
        *(f"Tiplog_{key} = {value}" for key, value in provenance.items()),
    ]
    with open(path, "wb") as f:
        f.write("\n".join([*head, *lines, "ElementDataFile = LOCAL", ""]).encode("ascii"))
        f.write(bytes(k))
    return k


@dataclass(frozen=True)
class SequenceFile:
    """A sequence file read back: per transform name, (n, 4, 4) [mm] and (n,) status."""

    timestamps_s: np.ndarray
    stamps_ns: np.ndarray
    transforms: dict[str, np.ndarray]
    status_ok: dict[str, np.ndarray]
    header: dict[str, str]


def read_sequence(path: Path) -> SequenceFile:
    """The project's own reader of what `write_sequence` writes (and PLUS's transform fields)."""
    raw = Path(path).read_bytes()
    end = raw.find(b"ElementDataFile")
    if end < 0:
        raise UserError(f"{path}: not a MetaIO file (no ElementDataFile line)")
    header: dict[str, str] = {}
    for line in raw[:end].decode("ascii", "replace").splitlines():
        key, sep, value = line.partition(" = ")
        if sep:
            header[key.strip()] = value.strip()
    n = int(header["DimSize"].split()[2])
    names = sorted(
        {
            k[len("Seq_Frame0000_") : -len("Transform")]
            for k in header
            if k.startswith("Seq_Frame0000_") and k.endswith("Transform")
        }
    )
    mats = {m: np.zeros((n, 4, 4)) for m in names}
    ok = {m: np.zeros(n, bool) for m in names}
    ts, stamps = np.zeros(n), np.zeros(n, np.int64)
    for k in range(n):
        f = f"Seq_Frame{k:04d}_"
        ts[k] = float(header[f + "Timestamp"])
        stamps[k] = int(header.get(f + "StampNs", "0"))
        for m in names:
            mats[m][k] = np.array(header[f"{f}{m}Transform"].split(), float).reshape(4, 4)
            ok[m][k] = header.get(f"{f}{m}TransformStatus", "OK") == "OK"
    return SequenceFile(ts, stamps, mats, ok, header)
