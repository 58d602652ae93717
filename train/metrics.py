"""Run logs: one JSON line per record (complete), CSV per stream (fixed columns), TensorBoard scalars."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path


class MetricsLog:
    """Writes ``metrics.jsonl``, ``<stream>.csv`` and TensorBoard events under ``run_dir``; appends on resume."""

    def __init__(self, run_dir: Path, tensorboard: bool = True):
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.jsonl = open(self.run_dir / "metrics.jsonl", "a")
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(self.run_dir / "tb"))
        self.columns: dict[str, list[str]] = {}

    def write(self, stream: str, step: int, values: dict) -> None:
        row = {"stream": stream, "step": int(step), **{k: _plain(v) for k, v in values.items()}}
        self.jsonl.write(json.dumps(row) + "\n")
        self.jsonl.flush()
        path = self.run_dir / f"{stream}.csv"
        if stream not in self.columns:
            if path.exists() and path.stat().st_size:
                with open(path) as f:
                    self.columns[stream] = next(csv.reader(f))
            else:
                self.columns[stream] = ["step", *sorted(values)]
                with open(path, "w", newline="") as f:
                    csv.writer(f).writerow(self.columns[stream])
        with open(path, "a", newline="") as f:
            csv.writer(f).writerow([row.get(c, "") for c in self.columns[stream]])
        if self.writer is not None:
            for key, value in values.items():
                if isinstance(value, (int, float)) and math.isfinite(value):
                    self.writer.add_scalar(f"{stream}/{key}", value, step)

    def close(self) -> None:
        self.jsonl.close()
        if self.writer is not None:
            self.writer.close()


def _plain(v):
    if hasattr(v, "item"):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v
