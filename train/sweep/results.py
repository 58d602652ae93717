"""A sweep's results as two tidy tables, from each trial's training log (and Tune's reports).

* ``curves``: a row per trial and report (every training iteration): the trial, its parameter
  values and seed, ``step`` and every metric reported.
* ``trials``: a row per trial: parameter values, seed, steps done and planned, whether it ran to
  the end, wall time, median env-steps/s, the Ray node that ran its last iteration, and for each
  summary column its final value (its mean over the last ``final_window`` reports, or, for an
  evaluation column with no value there, its last value), and the best value of the sweep's metric.

Both are written as CSV and Parquet beside the trials (``curves.csv``, ``trials.parquet``, ...).
The rows come from each trial's own training log (``run/metrics.jsonl``, written as it trains and
appended to across restarts; Tune's ``result.json`` of a restarted trial holds only the reports
since its restart). A trial restarted from a checkpoint logs some iterations twice; the later row
of a step is kept (a resumed run repeats the same numbers). Reports read these tables, not the
trial folders.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd

from train.sweep.spec import SweepSpec, load_folder
from train.sweep.trial import RUN_FOLDER

SUMMARY_SUFFIXES = ("team_reward", "_goal_pickups", "_wrong_pickups", "_net_pickups", "_goal_accuracy")
"""Columns the ``trials`` table summarises besides the sweep's metric."""
ID_COLUMNS = ("trial", "configuration", "seed")


def trial_values(spec: SweepSpec, params: dict) -> dict:
    """A trial's parameter values by name and its seed."""
    return {**spec.values(params), "seed": int(params["seed"])}


def read_jsonl(path: Path) -> list[dict]:
    """The records of a JSON-lines file; a line still being written is left out."""
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return rows


def training_rows(trial_dir: Path) -> dict[int, dict]:
    """A trial's training log by step: each iteration's ``train`` row with its evaluation (``eval/...``) and
    what only Tune's reports hold (the node and thread counts). The log is appended to across restarts: a
    repeated step keeps its later row (a resumed run repeats the same numbers)."""
    by_step: dict[int, dict] = {}
    for record in read_jsonl(trial_dir / RUN_FOLDER / "metrics.jsonl"):
        stream, step = record.pop("stream", "train"), int(record.pop("step"))
        prefix = "" if stream == "train" else f"{stream}/"
        by_step.setdefault(step, {}).update({prefix + k: v for k, v in record.items()})
    for report in read_jsonl(trial_dir / "result.json"):
        if int(report.get("step", -1)) in by_step:
            extra = {k: report[k] for k in ("node_id", "torch_threads", "numba_threads") if k in report}
            by_step[int(report["step"])].update(extra)
    return by_step


def collect(folder: str | Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Build (and write) the ``trials`` and ``curves`` tables of the sweep in ``folder``; works while it runs."""
    folder = Path(folder)
    spec = load_folder(folder)
    curves, trials = [], []
    for trial_dir in sorted(p for p in folder.iterdir() if p.is_dir() and (p / "params.json").exists()):
        params = json.loads((trial_dir / "params.json").read_text())
        values = trial_values(spec, params)
        by_step = training_rows(trial_dir)
        if not by_step:
            continue
        config = spec.config(spec.values(params), values["seed"])
        ident = {"trial": trial_dir.name, "configuration": spec.label(values), **values}
        rows = [{**ident, "step": step, **numeric(row)} for step, row in sorted(by_step.items())]
        curves.extend(rows)
        trials.append({**summarize_trial(spec, ident, rows, config.num_iterations * config.batch_steps),
                       "node": by_step[max(by_step)].get("node_id", "")})
    curves_df, trials_df = pd.DataFrame(curves), pd.DataFrame(trials)
    write_table(curves_df, folder / "curves")
    write_table(trials_df, folder / "trials")
    return trials_df, curves_df


def numeric(row: dict) -> dict:
    return {k: v for k, v in row.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}


def summary_columns(spec: SweepSpec, rows: list[dict]) -> list[str]:
    names = {k for row in rows for k in row}
    chosen = [spec.metric] + sorted(c for c in names if c != spec.metric and c.endswith(SUMMARY_SUFFIXES))
    return [c for c in dict.fromkeys(chosen) if c in names]


def summarize_trial(spec: SweepSpec, ident: dict, rows: list[dict], total_steps: int) -> dict:
    last = rows[-1]
    out = {**ident, "steps": int(last["step"]), "total_steps": total_steps,
           "wall_time_s": float(last.get("wall_time_s", math.nan)),
           "sps": float(pd.Series([r.get("sps", math.nan) for r in rows]).median())}
    out["finished"] = out["steps"] >= out["total_steps"]
    for column in summary_columns(spec, rows):
        every = pd.Series([r.get(column, math.nan) for r in rows], dtype=float)
        series, window = every.dropna(), every.iloc[-spec.final_window:].dropna()
        # an evaluation column has a value every eval_every reports: its last one when none falls in the window
        final = window.mean() if len(window) else (series.iloc[-1] if len(series) else math.nan)
        out[f"final_{column}"] = float(final)
        if column == spec.metric:
            best = series.max() if spec.mode == "max" else series.min()
            out[f"best_{column}"] = float(best) if len(series) else math.nan
    return out


def write_table(table: pd.DataFrame, stem: Path) -> None:
    from colorgrid.files import atomic_path

    with atomic_path(stem.with_suffix(".csv")) as tmp:
        table.to_csv(tmp, index=False)
    with atomic_path(stem.with_suffix(".parquet")) as tmp:
        table.to_parquet(tmp, index=False)


def read_tables(folder: str | Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    folder = Path(folder)
    return pd.read_parquet(folder / "trials.parquet"), pd.read_parquet(folder / "curves.parquet")
