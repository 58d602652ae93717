"""A sweep's results as two tidy tables, from each trial's training log (and Tune's reports).

* ``curves``: a row per trial and report (every training iteration): the trial, its parameter
  values and seed, ``step`` and every metric reported.
* ``trials``: a row per trial: parameter values, seed, steps done and planned, whether it ran to
  the end, wall time, median env-steps/s, the Ray node that ran its last iteration, and for each
  summary column its final value (its mean over the last ``final_window`` reports, or, for an
  evaluation column with no value there, its last value), and the best value of the sweep's metric.

Both are written as CSV and Parquet beside the trials (``curves.csv``, ``trials.parquet``, ...).

A sweep file's ``results`` folder keeps finished trials' results with the project (``publish``: the
trials table and the curves' main columns, as CSV): ``collect`` adds them to the sweep's own, and
``sweep run`` skips those trials, so a sweep spread over machines continues where it stands.
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

from train.sweep.checks import SUMMARY_SUFFIXES
from train.sweep.spec import WORKDIR_FILE, SweepError, SweepSpec, grid, load_folder
from train.sweep.trial import RUN_FOLDER

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


def trained_to(trial_dir: Path) -> int:
    """The last step a trial's training log reaches (0 before its first iteration): it has finished when that is
    its configuration's ``end_step``."""
    if not (trial_dir / RUN_FOLDER / "metrics.jsonl").is_file():
        return 0
    return max(training_rows(trial_dir), default=0)


def finished(spec, trial_dir: Path, params: dict) -> bool:
    """Whether the trial of ``params`` (its ``params.json``), in ``trial_dir``, has finished: its training log reaches
    its configuration's ``end_step``."""
    return trained_to(trial_dir) >= spec.config(spec.values(params), int(params["seed"])).end_step


CURVE_COLUMNS = ("wall_time_s", "sps", "penalty_coef", "team_reward")
"""Columns the kept curves hold besides the identity, the step, the metric and the summarised columns."""
UNFINISHED_FILE = "unfinished.csv"
"""The curves so far of the trials still running, kept beside the finished ones' (a long sweep's standing; no
report or claim reads them)."""
KEY = ("configuration", "seed")
"""What identifies a trial across machines: its configuration's label and its seed."""


def results_folder(spec: SweepSpec, folder: Path | None = None) -> Path | None:
    """The sweep's ``results`` folder, a relative one read from where the sweep was started (or the current
    folder)."""
    if spec.results is None or spec.results.is_absolute():
        return spec.results
    start = folder / WORKDIR_FILE if folder is not None else None
    base = Path(start.read_text().strip()) if start is not None and start.is_file() else Path.cwd()
    return base / spec.results


def committed(spec: SweepSpec, folder: Path | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The kept results (``trials``, ``curves``) of the sweep's finished trials; empty tables if none."""
    where = results_folder(spec, folder)
    if where is None or not (where / "trials.csv").is_file():
        return pd.DataFrame(), pd.DataFrame()
    trials = pd.read_csv(where / "trials.csv")
    curves = pd.read_csv(where / "curves.csv") if (where / "curves.csv").is_file() else pd.DataFrame()
    for table in (trials, curves):
        if "configuration" in table:
            table["configuration"] = table["configuration"].astype(str)
    # only the trials the file gives: a seed it no longer gives a configuration (seeds, [[more_seeds]]) is not kept
    keys = trial_keys(spec)
    wanted = [(str(c), int(s)) in keys for c, s in zip(trials["configuration"], trials["seed"])]
    trials = trials[wanted] if len(trials) else trials
    if not curves.empty and "trial" in curves:
        curves = curves[curves["trial"].isin(set(trials["trial"]))]
    return trials, curves


def trial_keys(spec: SweepSpec) -> set[tuple[str, int]]:
    """(configuration, seed) of every trial the sweep file gives (the random parameters' draws included)."""
    return {spec.key(params) for params in grid(spec)}


def committed_keys(spec: SweepSpec, folder: Path | None = None) -> set[tuple[str, int]]:
    """(configuration, seed) of every finished trial the results folder keeps."""
    trials, _ = committed(spec, folder)
    if trials.empty:
        return set()
    done = trials[trials["finished"].astype(bool)]
    return {(str(c), int(s)) for c, s in zip(done["configuration"], done["seed"])}


def merge_committed(spec: SweepSpec, folder: Path, trials: pd.DataFrame,
                    curves: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The sweep's own tables with the kept trials it does not hold finished itself."""
    kept_trials, kept_curves = committed(spec, folder)
    if kept_trials.empty:
        return trials, curves
    own = set() if trials.empty else {(str(c), int(s)) for c, s, f in
                                       zip(trials["configuration"], trials["seed"], trials["finished"]) if f}
    keys = [(str(c), int(s)) for c, s in zip(kept_trials["configuration"], kept_trials["seed"])]
    extra = kept_trials[[k not in own for k in keys]]
    if not trials.empty:  # an unfinished run of a kept trial gives way to the kept one
        kept = set(keys)
        trials = trials[[(str(c), int(s)) not in kept or (str(c), int(s)) in own
                         for c, s in zip(trials["configuration"], trials["seed"])]]
    trials = pd.concat([trials, extra], ignore_index=True)
    if not kept_curves.empty:
        extra_ids = set(extra["trial"])
        if not curves.empty:
            curves = curves[curves["trial"].isin(set(trials["trial"]))]
        curves = pd.concat([curves, kept_curves[kept_curves["trial"].isin(extra_ids)]], ignore_index=True)
    return trials, curves


def publish(folder: str | Path) -> tuple[Path, int]:
    """Keep the finished trials of the sweep in ``folder`` in its ``results`` folder (``trials.csv`` and the
    main columns of ``curves.csv``), beside those kept before, and the curves so far of the unfinished ones
    (``unfinished.csv``: the metric, team reward and timing by step; removed once every trial has finished);
    returns the folder and the trials kept."""
    folder = Path(folder)
    spec = load_folder(folder)
    where = results_folder(spec, folder)
    if where is None:
        raise SweepError(f"{spec.path}: the sweep file names no 'results' folder to keep its trials' results in")
    trials, curves = collect(folder)
    if trials.empty:
        return where, 0
    done = trials[trials["finished"].astype(bool)]
    main = (*ID_COLUMNS, *spec.param_names, "step", spec.metric, *CURVE_COLUMNS)
    keep = [c for c in curves.columns if c in main or c.removeprefix("eval/").endswith(SUMMARY_SUFFIXES)]
    where.mkdir(parents=True, exist_ok=True)
    write_csv(done, where / "trials.csv")
    finished = curves["trial"].isin(set(done["trial"]))
    write_csv(curves[finished][keep], where / "curves.csv")
    if finished.all():
        (where / UNFINISHED_FILE).unlink(missing_ok=True)
    else:
        write_csv(curves[~finished][[c for c in keep if c in main]], where / UNFINISHED_FILE)
    return where, len(done)


def write_csv(table: pd.DataFrame, path: Path) -> None:
    from colorgrid.files import atomic_path

    with atomic_path(path) as tmp:
        table.to_csv(tmp, index=False, float_format="%.6g")


def collect(folder: str | Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Build (and write) the ``trials`` and ``curves`` tables of the sweep in ``folder``, the trials kept in its
    ``results`` folder included; works while it runs."""
    folder = Path(folder)
    spec = load_folder(folder)
    curves, trials = [], []
    for trial_dir in sorted(p for p in folder.iterdir() if p.is_dir() and (p / "params.json").exists()):
        params = json.loads((trial_dir / "params.json").read_text())
        if "pack" in params:  # a Tune trial that trains a pack: its trials have folders of their own beside it
            continue
        if not spec.wants(params):  # a seed the sweep file no longer gives this configuration
            continue
        values = trial_values(spec, params)
        by_step = training_rows(trial_dir)
        if not by_step:
            continue
        config = spec.config(spec.values(params), values["seed"])
        ident = {"trial": trial_dir.name, "configuration": spec.label(values), **values}
        rows = [{**ident, "step": step, **numeric(row)} for step, row in sorted(by_step.items())]
        curves.extend(rows)
        trials.append({**summarize_trial(spec, ident, rows, config.end_step),
                       "node": by_step[max(by_step)].get("node_id", "")})
    trials_df, curves_df = merge_committed(spec, folder, pd.DataFrame(trials), pd.DataFrame(curves))
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
