"""A sweep's results as two tidy tables, from what Tune wrote for each trial.

* ``curves``: a row per trial and report (every training iteration): the trial, its parameter
  values and seed, ``step`` and every metric reported.
* ``trials``: a row per trial: parameter values, seed, steps done and planned, whether it ran to
  the end, wall time, median env-steps/s, the Ray node that ran its last iteration, and for each
  summary column its final value (its mean over the last ``final_window`` reports, or, for an
  evaluation column with no value there, its last value), and the best value of the sweep's metric.

Both are written as CSV and Parquet beside the trials (``curves.csv``, ``trials.parquet``, ...).
A trial restarted from a checkpoint reports some iterations twice; the later report of a step is
kept (a resumed run repeats the same numbers). Reports read these tables, not the trial folders.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pandas as pd

from train.sweep.spec import SPEC_FILE, SweepSpec, load_sweep

SUMMARY_SUFFIXES = ("team_reward", "_goal_pickups", "_wrong_pickups", "_net_pickups", "_goal_accuracy")
"""Columns the ``trials`` table summarises besides the sweep's metric."""
ID_COLUMNS = ("trial", "configuration", "seed")


def load_spec(folder: Path) -> SweepSpec:
    spec = load_sweep(folder / SPEC_FILE, out=folder)
    return dataclasses.replace(spec, name=folder.name)


def trial_values(spec: SweepSpec, params: dict) -> dict:
    """A trial's parameter values by name (listed values, option labels and random draws) and its seed."""
    values = {p.name: params.get(p.name) for p in spec.params if not p.random}
    values.update(params.get("sample") or {})
    return {**values, "seed": int(params["seed"])}


def configuration_label(spec: SweepSpec, values: dict) -> str:
    parts = []
    for p in spec.params:
        v = values.get(p.name)
        parts.append(f"{p.name}={v:.3g}" if isinstance(v, float) and p.random else f"{p.name}={v}")
    return ", ".join(parts) or "base"


def read_reports(trial_dir: Path) -> list[dict]:
    path = trial_dir / "result.json"
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        if line.strip():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:  # a report being written as we read
                continue
    return rows


def collect(folder: str | Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Build (and write) the ``trials`` and ``curves`` tables of the sweep in ``folder``; works while it runs."""
    folder = Path(folder)
    spec = load_spec(folder)
    curves, trials = [], []
    for trial_dir in sorted(p for p in folder.iterdir() if p.is_dir() and (p / "params.json").exists()):
        params = json.loads((trial_dir / "params.json").read_text())
        values = trial_values(spec, params)
        reports = read_reports(trial_dir)
        by_step = {}
        for report in reports:
            if "step" in report:
                by_step[int(report["step"])] = report  # a restarted trial's repeated step: the later report
        if not by_step:
            continue
        ident = {"trial": trial_dir.name, "configuration": configuration_label(spec, values), **values}
        rows = [{**ident, **numeric(report)} for _, report in sorted(by_step.items())]
        curves.extend(rows)
        trials.append({**summarize_trial(spec, ident, rows), "node": by_step[max(by_step)].get("node_id", "")})
    curves_df, trials_df = pd.DataFrame(curves), pd.DataFrame(trials)
    write_table(curves_df, folder / "curves")
    write_table(trials_df, folder / "trials")
    return trials_df, curves_df


def numeric(report: dict) -> dict:
    skip = {"trial_id", "date", "hostname", "node_ip", "pid", "config", "done", "timestamp", "time_this_iter_s",
            "time_total_s", "time_since_restore", "iterations_since_restore", "training_iteration", "checkpoint_dir_name",
            "should_checkpoint"}
    return {k: v for k, v in report.items() if k not in skip and isinstance(v, (int, float)) and not isinstance(v, bool)}


def summary_columns(spec: SweepSpec, rows: list[dict]) -> list[str]:
    names = {k for row in rows for k in row}
    chosen = [spec.metric] + sorted(c for c in names if c != spec.metric and c.endswith(SUMMARY_SUFFIXES))
    return [c for c in dict.fromkeys(chosen) if c in names]


def summarize_trial(spec: SweepSpec, ident: dict, rows: list[dict]) -> dict:
    last = rows[-1]
    out = {**ident, "steps": int(last["step"]), "total_steps": int(last.get("total_steps", last["step"])),
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
