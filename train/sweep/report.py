"""A sweep's report: per configuration, the mean and 95% interval across seeds of each final metric, the
paper's figure where the sweep file gives one, and learning curves (mean with a 95% band across seeds).

It reads the tables of ``results`` (collected afresh, so the report of a running sweep shows the
trials that have reported so far) and writes ``report.md`` and ``curves_<metric>.png`` beside them,
with each of the sweep file's claims decided (``claims``: the difference, its interval, p and the
verdict), also as ``claims.csv``. Given a sweep file instead of a folder, it reports the finished
trials kept in the file's ``results`` folder, and writes there.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from train.sweep import claims as claim_rules
from train.sweep.claim_table import format_claims
from train.sweep.claim_table import table as claims_table
from train.sweep.declared import DECLARED_FILE
from train.sweep.looks import HISTORY_FILE, record
from train.sweep.claim_spec import matches
from train.sweep.results import collect, committed, publish, results_folder
from train.sweep.spec import SweepError, SweepSpec, load_folder, load_sweep


def t_quantile(df: int) -> float:
    """Student's t 97.5% quantile for ``df`` degrees of freedom (a two-sided 95% interval)."""
    from scipy import stats

    return float(stats.t.ppf(0.975, df))


def mean_interval(values) -> tuple[float, float, int]:
    """Mean, the half-width of its 95% Student-t interval (NaN for one value), and the count."""
    values = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    n = len(values)
    if n == 0:
        return math.nan, math.nan, 0
    half = t_quantile(n - 1) * values.std(ddof=1) / math.sqrt(n) if n > 1 else math.nan
    return float(values.mean()), float(half), n


def paper_value(spec: SweepSpec, row: pd.Series) -> str:
    for figure in spec.paper:
        if matches(figure.where, row):
            return f"{figure.value:+.1f}" + (f" ({figure.note})" if figure.note else "")
    return ""


def summary(spec: SweepSpec, trials: pd.DataFrame) -> pd.DataFrame:
    """A row per configuration: seeds, finished trials, and mean / 95% half-width of each final column over its
    finished trials (over every trial while none has finished)."""
    finals = [c for c in trials.columns if c.startswith("final_")]
    rows = []
    for label, group in trials.groupby("configuration", sort=False):
        row = {"configuration": label, **{p.name: group[p.name].iloc[0] for p in spec.params},
               "seeds": len(group), "finished": int(group["finished"].sum()),
               "steps": int(group["steps"].min()), "wall_time_s": float(group["wall_time_s"].mean())}
        done = group[group["finished"].astype(bool)]
        counted = done if len(done) else group  # a trial still running is not averaged with finished ones
        for column in finals:
            mean, half, _ = mean_interval(counted[column])
            row[f"{column}_mean"], row[f"{column}_ci95"] = mean, half
        rows.append(row)
    return pd.DataFrame(rows)


def format_summary(spec: SweepSpec, table: pd.DataFrame) -> str:
    """The summary as a Markdown table: the metric and the other team figures, with the paper's number."""
    metric = f"final_{spec.metric}"
    finals = [c[len("final_"):-len("_mean")] for c in table.columns if c.startswith("final_") and c.endswith("_mean")]
    shown = ("team_reward", "eval/team_reward")
    extra = [c for c in finals if c != spec.metric and (c in shown or (not c.startswith("eval/") and c.endswith(
        ("_net_pickups", "_wrong_pickups"))))]  # the rest is in summary.csv
    head = ["configuration", "seeds (finished)", "steps", f"{spec.metric} (final, 95% CI)"]
    head += (["paper"] if spec.paper else []) + [f"{c}" for c in extra]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, row in table.iterrows():
        cells = [row["configuration"], f"{row['seeds']} ({row['finished']})", f"{row['steps']:,}",
                 interval(row[f"{metric}_mean"], row[f"{metric}_ci95"])]
        if spec.paper:
            cells.append(paper_value(spec, row))
        cells += [interval(row[f"final_{c}_mean"], row[f"final_{c}_ci95"]) for c in extra]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines)


def interval(mean: float, half: float) -> str:
    if not math.isfinite(mean):
        return "-"
    return f"{mean:+.2f}" + (f" ± {half:.2f}" if math.isfinite(half) else "")


def plot_curves(spec: SweepSpec, curves: pd.DataFrame, column: str, out: Path) -> Path | None:
    """Each configuration's ``column`` against env steps: the mean across its seeds, with a 95% band."""
    if column not in curves.columns:
        return None
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    smooth = max(1, spec.final_window)
    colors = {}
    for label, group in curves.groupby("configuration", sort=False):
        per_seed = group.pivot_table(index="step", columns="trial", values=column)
        per_seed = per_seed.rolling(smooth, min_periods=1).mean()  # each seed's running mean, as the final value
        stats = [mean_interval(values) for values in per_seed.to_numpy()]
        mean = np.array([s[0] for s in stats])
        half = np.nan_to_num(np.array([s[1] for s in stats]))
        steps = per_seed.index.to_numpy()
        line, = ax.plot(steps, mean, label=f"{label} ({per_seed.shape[1]} seeds)")
        ax.fill_between(steps, mean - half, mean + half, color=line.get_color(), alpha=0.2, linewidth=0)
        colors[label] = (line.get_color(), group.iloc[0])
    if column == spec.metric:  # the paper's figures are of the metric: each in its configuration's color
        for figure in spec.paper:
            color = next((c for c, row in colors.values() if matches(figure.where, row)), "gray")
            ax.axhline(figure.value, color=color, linestyle=":", linewidth=1.2)
    ax.set_xlabel("env steps")
    ax.set_ylabel(f"{column} (running mean of {smooth} reports)")
    dotted = " (dotted: the paper's figures)" if spec.paper and column == spec.metric else ""
    ax.set_title(f"{spec.name}: mean across seeds, 95% band{dotted}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def write_report(path: str | Path) -> tuple[str, list[Path]]:
    """Report a sweep: a sweep's folder (its tables collected afresh, kept trials included; written there), or a
    sweep file (the trials kept in its ``results`` folder; written there). Returns the text and the pictures."""
    path = Path(path)
    if path.is_dir():
        spec = load_folder(path)
        trials, curves = collect(path)
        return render(spec, trials, curves, path)
    spec = load_sweep(path)
    out = results_folder(spec)
    if out is None:
        raise SweepError(f"{spec.path}: the sweep file names no 'results' folder; report a sweep's folder instead "
                         f"(colorgrid sweep report runs/sweeps/{spec.name})")
    trials, curves = committed(spec)
    return render(spec, trials, curves, out)


def publish_report(folder: str | Path) -> tuple[Path, int, str]:
    """Keep the finished trials of the sweep in ``folder`` in its results folder, and report them there."""
    spec = load_folder(folder)
    where, count = publish(folder)
    trials, curves = committed(spec, Path(folder))
    text, _ = render(spec, trials, curves, where)
    if spec.claims and not trials.empty:  # the record of what this published report decided, on which seeds
        record(spec, claim_rules.evaluate(spec, trials), where)
    return where, count, text


def render(spec: SweepSpec, trials: pd.DataFrame, curves: pd.DataFrame, out: Path) -> tuple[str, list[Path]]:
    """Write ``report.md``, ``summary.csv``, ``claims.csv`` and the curve pictures of these tables into ``out``."""
    if trials.empty:
        return f"sweep {spec.name}: no trial has reported yet", []
    out.mkdir(parents=True, exist_ok=True)
    table = summary(spec, trials)
    pictures = [p for c in dict.fromkeys([spec.metric, "team_reward"])
                if (p := plot_curves(spec, curves, c, out / f"curves_{c.replace('/', '_')}.png"))]
    outcomes = claim_rules.evaluate(spec, trials)
    done = int(trials["finished"].sum())
    claims_text = [] if not outcomes else [
        "## Claims", "",
        f"Each side's values are its finished trials' finals (one per seed). The test: Welch's t-test between "
        f"configurations, paired by seed against a baseline evaluated on each seed's own evaluation episodes, "
        f"one-sample against a threshold; for '~' also two one-sided tests within the margin and the one-sided test "
        f"beyond it. a - b is printed with the test's interval at the claim's level (1 - level, two-sided; for '~' "
        f"1 - 2 level, the interval the one-sided tests read). The file's claims are one family: "
        f"each p is adjusted by Holm's method across them, and the verdict reads the adjusted p at the claim's "
        f"level, {claim_rules.ALPHA} divided by its looks (counted from the file's plan and the record in "
        f"{HISTORY_FILE}). Verdicts by one rule (train/sweep/claims.py, docs/SWEEPS.md): reproduced (the paper's "
        f"direction, adjusted p < level), in direction only (the paper's direction, not shown: undecided), not "
        f"reproduced (the opposite, adjusted p < level), inconclusive otherwise. A claim declared or changed after "
        f"trials of its configurations finished ({DECLARED_FILE}, written by sweep run) is exploratory: its "
        f"figures are printed, its verdict is not given. A claim whose seeds fall short of the look the file plans "
        f"(trials still to run) is interim: its figures are printed, its verdict waits for that look.", "",
        format_claims(outcomes), ""]
    text = "\n".join([
        f"# Sweep {spec.name}", "",
        spec.description, "",
        f"{len(trials)} of {spec.num_trials()} trials have reported; {done} ran to the end. A final value is a "
        f"trial's mean over its last {spec.final_window} iterations (an evaluation column: its evaluations "
        f"there, or its last one); ± is the half-width of a 95% Student-t interval "
        f"across seeds, over a configuration's finished trials once it has any.", "",
        format_summary(spec, table), "",
        *claims_text,
        *[f"![{p.stem}]({p.name})" for p in pictures], ""])
    (out / "report.md").write_text(text)
    table.to_csv(out / "summary.csv", index=False)
    if outcomes:
        claims_table(outcomes).to_csv(out / "claims.csv", index=False)
    return text, pictures
