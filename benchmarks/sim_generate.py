"""Time to generate the full translation protocol (300 trials) in the measurement tier, and
messages per second, split into robot simulation, sensor/vision models, encoding and writing."""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from services.bench.scenario import load_scenario
from services.bench.session import generate


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenario", default="translation")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=None, help="cut the protocol (default: all of it)")
    ap.add_argument("--out", default=None, help="keep the file here (default: a temporary file)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    sc = load_scenario(args.scenario)
    with tempfile.TemporaryDirectory() as d:
        out = Path(args.out) if args.out else Path(d) / "session.mcap"
        s = generate(sc, out, seed=args.seed, duration_s=args.duration)
        size = out.stat().st_size
    t = s["timings"]
    res = {
        "scenario": args.scenario,
        "session_s": round(s["duration_s"], 1),
        "trials": s["trials"],
        "messages": s["messages"],
        "total_s": round(t["total_s"], 2),
        "robot_s": round(t["robot_s"], 2),
        "models_s": round(t["models_s"], 2),
        "encode_s": round(t["encode_s"], 2),
        "write_s": round(t["write_s"], 2),
        "messages_per_s": round(s["messages"] / t["total_s"]),
        "messages_per_s_without_robot": round(s["messages"] / (t["total_s"] - t["robot_s"])),
        "real_time_factor": round(s["duration_s"] / t["total_s"], 1),
        "file_mb": round(size / 2**20, 1),
    }
    if args.json:
        print(json.dumps(res))
    else:
        for k, v in res.items():
            print(f"{k:>30}: {v}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
