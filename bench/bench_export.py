"""Export speed: one 128-step replay to GIF and to MP4, median over repeats.

Usage: python bench/bench_export.py [--replay FILE] [--repeats 3] [--scale 12]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, timed  # noqa: E402

from colorgrid.replay.export import export  # noqa: E402
from colorgrid.replay import load  # noqa: E402

DEFAULT = Path(__file__).resolve().parents[1] / "replays/default/astar+bayes_seed2026.replay.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--replay", type=Path, default=DEFAULT)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scale", type=int, default=12)
    args = parser.parse_args()
    replay = load(args.replay)
    print(f"machine: {machine()}")
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in ("gif", "mp4"):
            out = Path(tmp) / f"episode.{fmt}"
            wall, cpu = timed(lambda: export(replay, out, fmt, cell=args.scale), args.repeats)
            size = out.stat().st_size / 1e6
            print(f"{fmt}: {replay.num_steps} steps in {wall:.2f} s wall, {cpu:.2f} s CPU (median), {size:.2f} MB")


if __name__ == "__main__":
    main()
