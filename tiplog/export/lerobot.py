"""LeRobot dataset format v3.0, written with pyarrow (no lerobot, no torch needed).

Layout (as lerobot 0.4's `LeRobotDataset` reads it):
- `meta/info.json`: `codebase_version` "v3.0", `fps`, `features` (dtype, shape, names), totals,
  `data_path` / `video_path` patterns, `chunks_size`, `splits`;
- `data/chunk-000/file-000.parquet`: one row per frame, every feature a column;
- `meta/episodes/chunk-000/file-000.parquet`: one row per episode (its length, its row range
  `dataset_from_index` / `dataset_to_index`, where its data lives, its per-feature stats);
- `meta/tasks.parquet`: the task strings (index) and their `task_index`;
- `meta/stats.json`: per feature min, max, mean, std, count and the q01..q99 quantiles.

One episode per segment (the whole recording, or the stretches between the recorder's event
marks), split further where the estimate has a gap (frames must be `1 / fps` apart).
Features: `observation.state` = tip position (3, m, base frame), shaft quaternion (4, x y z w,
R_base_tool, its sign continuous within an episode), insertion depth (mm), roll (deg); `action` = the next frame's state (the
episode's last frame repeats its own); `observation.stamp_ns`, the host-clock stamp of the
fusion state each row holds (the row's `timestamp` is exactly `frame_index / fps`); and,
where the recording has them, `observation.images.vision_preview` (vision/preview) and
`observation.images.camera` (camera/image) as MPEG-4 video, `videos/<key>/chunk-000/file-000.mp4`,
frame k the image at or before row k's state (`tiplog.export.video`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from tiplog.export.track import Frames, Track

CODEBASE_VERSION = "v3.0"
STATE_NAMES = ["tip_x_m", "tip_y_m", "tip_z_m", "shaft_qx", "shaft_qy", "shaft_qz", "shaft_qw", "depth_mm", "roll_deg"]
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-000/file-000.parquet"
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)


def state_rows(track: Track, rows: np.ndarray) -> np.ndarray:
    """(m, 9) float32 observation.state of consecutive track rows. q and -q are one rotation:
    each quaternion takes the sign that keeps it continuous with the row before (a learner
    sees no jump where the filter's sign flips)."""
    q = track.q_base_tool_xyzw[rows].copy()
    flips = np.concatenate([[False], np.einsum("ij,ij->i", q[1:], q[:-1]) < 0])
    q *= np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)[:, None]
    return np.column_stack([track.p_tip_base_m[rows], q, track.depth_mm[rows], track.roll_deg[rows]]).astype(np.float32)


def episodes_of(segments: Sequence[Frames]) -> list[tuple[Frames, np.ndarray]]:
    """(segment, grid positions) of each run of valid frames with at least 2 frames."""
    out = []
    for seg in segments:
        idx = np.flatnonzero(seg.valid)
        if len(idx) == 0:
            continue
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
        out += [(seg, r) for r in runs if len(r) >= 2]
    return out


def _stats(x: np.ndarray) -> dict[str, list]:
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    out = {
        "min": x.min(0).tolist(),
        "max": x.max(0).tolist(),
        "mean": x.mean(0).tolist(),
        "std": x.std(0).tolist(),
        "count": [len(x)],
    }
    for q in QUANTILES:
        out[f"q{int(round(q * 100)):02d}"] = np.quantile(x, q, axis=0).tolist()
    return out


def tasks_table(tasks: list[str]) -> pa.Table:
    """meta/tasks.parquet as lerobot writes it with pandas: `task_index` with the task strings
    as the frame's index (stored as `__index_level_0__`, named in the pandas metadata)."""
    pandas_meta = {
        "index_columns": ["__index_level_0__"],
        "column_indexes": [],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {
                "name": None,
                "field_name": "__index_level_0__",
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": None,
            },
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.0",
    }
    schema = pa.schema(
        [("task_index", pa.int64()), ("__index_level_0__", pa.string())],
        metadata={b"pandas": json.dumps(pandas_meta).encode()},
    )
    return pa.table([pa.array(range(len(tasks)), pa.int64()), pa.array(tasks, pa.string())], schema=schema)


def features(fps: int) -> dict[str, dict]:
    names = {"motors": STATE_NAMES}
    return {
        "observation.state": {"dtype": "float32", "shape": [9], "names": names},
        "action": {"dtype": "float32", "shape": [9], "names": names},
        "observation.stamp_ns": {"dtype": "int64", "shape": [1], "names": None},
        "timestamp": {"dtype": "float32", "shape": [1], "names": None},
        "frame_index": {"dtype": "int64", "shape": [1], "names": None},
        "episode_index": {"dtype": "int64", "shape": [1], "names": None},
        "index": {"dtype": "int64", "shape": [1], "names": None},
        "task_index": {"dtype": "int64", "shape": [1], "names": None},
    }


def write_dataset(
    out: Path,
    track: Track,
    segments: Sequence[Frames],
    fps: int,
    task: str,
    recording: Path | None = None,
    image_topics: Sequence[str] = (),
) -> dict[str, int]:
    """Write the dataset into the (new, empty) folder `out`, with one video feature per topic
    of `image_topics` (read from `recording`); returns episode, frame and video counts."""
    eps = episodes_of(segments)
    cols: dict[str, list[np.ndarray]] = {k: [] for k in features(fps)}
    ep_rows = []
    start = 0
    for e, (seg, pos) in enumerate(eps):
        rows = seg.index[pos]
        n = len(rows)
        state = state_rows(track, rows)
        action = np.vstack([state[1:], state[-1:]])
        frame = np.arange(n, dtype=np.int64)
        per = {
            "observation.state": state,
            "action": action,
            "observation.stamp_ns": track.t_ns[rows].astype(np.int64),
            "timestamp": (frame / fps).astype(np.float32),
            "frame_index": frame,
            "episode_index": np.full(n, e, np.int64),
            "index": start + frame,
            "task_index": np.zeros(n, np.int64),
        }
        for k, v in per.items():
            cols[k].append(v)
        row = {
            "episode_index": e,
            "tasks": [task],
            "length": n,
            "data/chunk_index": 0,
            "data/file_index": 0,
            "dataset_from_index": start,
            "dataset_to_index": start + n,
            "meta/episodes/chunk_index": 0,
            "meta/episodes/file_index": 0,
            "tiplog/segment": int(seg.segment),
            "tiplog/first_stamp_ns": int(track.t_ns[rows[0]]),
        }
        for k, v in per.items():
            for stat, value in _stats(v).items():
                row[f"stats/{k}/{stat}"] = value
        ep_rows.append(row)
        start += n
    data = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    table = pa.table(
        {
            "observation.state": pa.array(list(data["observation.state"]), pa.list_(pa.float32(), 9)),
            "action": pa.array(list(data["action"]), pa.list_(pa.float32(), 9)),
            **{k: pa.array(data[k]) for k in features(fps) if k not in ("observation.state", "action")},
        }
    )
    (out / "data/chunk-000").mkdir(parents=True)
    pq.write_table(table, out / DATA_PATH.format(chunk_index=0, file_index=0))
    (out / "meta/episodes/chunk-000").mkdir(parents=True)
    pq.write_table(tasks_table([task]), out / "meta/tasks.parquet")
    stats = {k: _stats(v) for k, v in data.items()} if start else {}
    feats = features(fps)
    videos = []
    if start and image_topics:
        from tiplog.export.video import CODEC, IMAGE_TOPICS, write_video

        for topic in image_topics:
            key = IMAGE_TOPICS[topic]
            path = out / VIDEO_PATH.format(video_key=key, chunk_index=0, file_index=0)
            path.parent.mkdir(parents=True)
            v = write_video(recording, topic, data["observation.stamp_ns"], fps, path)
            videos.append(v)
            feats[key] = {
                "dtype": "video",
                "shape": [v.height, v.width, 3],
                "names": ["height", "width", "channels"],
                "info": {
                    "video.height": v.height, "video.width": v.width, "video.codec": "mpeg4" if CODEC == "mp4v" else CODEC,
                    "video.pix_fmt": "yuv420p", "video.is_depth_map": False, "video.fps": fps, "video.channels": 3,
                    "has_audio": False,
                },
            }  # fmt: skip
            stats[key] = v.stats
            for row in ep_rows:  # every episode's frames lie in the one file, in order
                row[f"videos/{key}/chunk_index"] = 0
                row[f"videos/{key}/file_index"] = 0
                row[f"videos/{key}/from_timestamp"] = row["dataset_from_index"] / fps
                row[f"videos/{key}/to_timestamp"] = row["dataset_to_index"] / fps
    pq.write_table(pa.Table.from_pylist(ep_rows), out / EPISODES_PATH)
    info = {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": "tiplog_handheld_instrument",
        "total_episodes": len(eps),
        "total_frames": start,
        "total_tasks": 1,
        "chunks_size": 1000,
        "data_files_size_in_mb": 100,
        "video_files_size_in_mb": 200,
        "fps": fps,
        "splits": {"train": f"0:{len(eps)}"},
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH if videos else None,
        "features": feats,
    }
    (out / "meta/info.json").write_text(json.dumps(info, indent=4))
    (out / "meta/stats.json").write_text(json.dumps(stats, indent=4))
    return {"episodes": len(eps), "frames": start, "videos": len(videos)}
