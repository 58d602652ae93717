"""``colorgrid study power``: how many participants an arm of a study needs, from a pilot's spread.

A study compares the levels of a factor (``leader = ["astar", "person:..."]``) on a measure of its ``trials`` table
(``stated_accuracy``, ``follower_net_pickups``, ...). Given the smallest difference worth finding on that measure, the
pilot export's spread gives the effect size, and the t-test's power (``t_test_power``) the sample size, for the study's
design:

- **within participants** (``design.assignment = "within"``: every participant meets every condition): each
  participant's difference between the two levels (their mean over the trials at one level minus their mean at the
  other), the paired t-test on ``d_z = difference / sd(differences)``. The participants needed are
  spread over the arms (the orders), so that each order is used equally often: a multiple of the number of arms.
- **between participants**: each participant's mean at their one level, the two-sample t-test (equal groups) on
  Cohen's ``d = difference / pooled sd``; each level's group is spread over the arms (conditions) that have that level.

Both are two-sided at level ``alpha``. A factor of more than two levels is taken pair by pair; the study needs what
its hardest pair needs. A pilot is a handful of participants: its spread is itself uncertain, and the numbers it gives
are a plan, not a guarantee.

The pilot's excluded trials are left out as the study's analysis leaves them out (``drop_excluded``: each trial its
``exclusions`` table names, and every trial of a participant it excludes as a whole), unless they are kept on purpose.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from colorgrid.extras import require
from server.study.assign import arms
from server.study.config import Study
from server.study.exclusions import RULES, counted
from server.study.schema import export_schema

NUMERIC = ("int64", "Int64", "float64")
"""The declared column types a measure may have."""


@dataclass(frozen=True)
class Comparison:
    """What a sample size is for: a factor's two levels, compared on a measure, with the smallest difference worth
    finding, at a power and a significance level."""

    measure: str
    """A numeric column of the export's ``trials`` table (``stated_accuracy``, ``follower_net_pickups``, ...)."""
    difference: float
    """The smallest difference between the levels worth finding, in the measure's units (> 0)."""
    factor: str | None = None
    """The factor whose levels are compared (default: the study's first factor of two levels or more)."""
    power: float = 0.8
    """The chance of finding a true difference of that size (in (0, 1))."""
    alpha: float = 0.05
    """The two-sided significance level (in (0, 1))."""

    def __post_init__(self):
        if not math.isfinite(self.difference) or self.difference <= 0:
            raise ValueError(f"--difference {self.difference:g} is invalid: a positive number, in the measure's units")
        for name in ("power", "alpha"):
            value = getattr(self, name)
            if not 0 < value < 1:
                raise ValueError(f"--{name} {value:g} is invalid: a number between 0 and 1")


def measures(study: Study) -> list[str]:
    """The ``trials`` columns a sample size can be computed for: the numeric ones, but the indices and counters of
    the record (``arm``, ``trial_index``, ``attempt``, ...) and the condition's settings (``condition_*``: the
    factors, not measures)."""
    record = {"arm", "trial_index", "attempt", "page_step"}
    return [c.name for c in export_schema(study)["trials"].columns
            if c.type in NUMERIC and c.name not in record and not c.name.startswith("condition_")]


def read_trials(folder: Path) -> pd.DataFrame:
    """The counted trials of a study's export folder (``colorgrid study export --out``): not the practice, and not an
    attempt lost to no one's doing (``Ending.lost()``: disconnected, the server stopped), which the participant played
    again, nor one still running; as the admin page counts them."""
    path = Path(folder) / "trials.parquet"
    if not path.is_file():
        raise FileNotFoundError(f"--pilot {folder}: no trials.parquet there; give the folder `colorgrid study export "
                                "--out` wrote")
    trials = pd.read_parquet(path)
    ended = trials.ended.astype(object).where(trials.ended.notna(), None)
    return trials[[counted(kind, end) for kind, end in zip(trials.kind, ended)]]


def read_exclusions(folder: Path) -> pd.DataFrame:
    """The ``exclusions`` table of a study's export folder: a row per rule a trial or a participant broke."""
    path = Path(folder) / "exclusions.parquet"
    if not path.is_file():
        raise FileNotFoundError(f"--pilot {folder}: no exclusions.parquet there; export the pilot again (colorgrid "
                                "study export), or give --keep-excluded to plan on every trial")
    return pd.read_parquet(path)


def drop_excluded(trials: pd.DataFrame, exclusions: pd.DataFrame) -> tuple[pd.DataFrame, dict]:
    """``trials`` without the excluded, read from ``exclusions`` as docs/STUDIES.md's analysis reads it: every trial of
    a participant excluded as a whole (a row without a game), and each trial a row names (its ``game_id``); and what
    was left out: ``trials`` (all of them) ``of`` the trials given, the ``participants`` excluded as a whole with
    their ``participant_trials`` and ``participant_rules`` (participants per rule), and the ``excluded_trials`` of the
    other participants with their ``trial_rules`` (trials per rule; a trial may break several)."""
    if "game_id" not in trials.columns:
        raise ValueError("the pilot's trials table has no column 'game_id' to match its exclusions to: export the "
                         "pilot with colorgrid study export, or give --keep-excluded")
    whole = exclusions[exclusions.game_id.isna()]
    theirs = trials.participant.isin(whole.participant)
    own = ~theirs & trials.game_id.isin(exclusions.game_id.dropna())
    participants = set(trials.participant[theirs])
    return trials[~theirs & ~own], {
        "trials": int(theirs.sum() + own.sum()), "of": len(trials),
        "participants": len(participants), "participant_trials": int(theirs.sum()),
        "participant_rules": _per_rule(whole[whole.participant.isin(participants)], "participant"),
        "excluded_trials": int(own.sum()),
        "trial_rules": _per_rule(exclusions[exclusions.game_id.isin(trials.game_id[own])], "game_id")}


def _per_rule(rows: pd.DataFrame, what: str) -> dict[str, int]:
    """How many distinct ``what`` each rule of ``rows`` names, in the order of ``exclusions.RULES``."""
    counts = rows.groupby(rows.rule.astype(str))[what].nunique()
    return {rule: int(counts[rule]) for rule in RULES if rule in counts}


def pilot_trials(folder: Path, keep_excluded: bool = False) -> tuple[pd.DataFrame, dict | None]:
    """The pilot's counted trials a plan is made on (``read_trials``), the excluded left out (``drop_excluded``), and
    what was left out; with ``keep_excluded`` every counted trial, and None."""
    trials = read_trials(folder)
    if keep_excluded:
        return trials, None
    return drop_excluded(trials, read_exclusions(folder))


def factor_levels(study: Study, factor: str | None) -> tuple[str, list]:
    """The factor compared and its levels, as the study file declares them."""
    varied = [name for name, levels in study.factors.items() if len(levels) > 1]
    if factor is None:
        if not varied:
            raise ValueError("the study has no factor of two levels or more: there is nothing to compare")
        factor = varied[0]
    if factor not in varied:
        raise ValueError(f"--factor {factor!r} is invalid: a factor of the study with two levels or more, one of "
                         f"{varied}")
    return factor, list(study.factors[factor])


def sample_size(study: Study, trials: pd.DataFrame, comparison: Comparison) -> dict:
    """Participants needed, per pair of the factor's levels and for the study (the hardest pair), from the pilot's
    ``trials`` (module docstring). Raises ``ValueError`` naming what is wrong with the measure, factor or pilot."""
    require("study", "colorgrid study power", only=("scipy",))
    allowed = measures(study)
    if comparison.measure not in allowed:
        raise ValueError(f"--measure {comparison.measure!r} is invalid: a numeric column of the trials table, one "
                         f"of {allowed}")
    factor, levels = factor_levels(study, comparison.factor)
    within = study.design.assignment == "within"
    column = f"condition_{factor}"
    for name in (comparison.measure, column, "participant"):
        if name not in trials.columns:
            raise ValueError(f"the pilot's trials table has no column {name!r}: export the pilot with this study file "
                             "(colorgrid study export)")
    kept = trials[[column, "participant", comparison.measure]].dropna()
    means = kept.groupby(["participant", column], observed=True)[comparison.measure].mean().unstack(column)
    num_arms = len(arms(study))
    pairs = []
    for a, b in itertools.combinations(levels, 2):
        if within:
            both = means.reindex(columns=[a, b]).dropna()
            spread = _spread(both[a] - both[b], f"{factor} {a!r} - {b!r}, within participants")
            effect = comparison.difference / spread
            total = participants_needed(effect, comparison.alpha, comparison.power, paired=True)
            per_arm = math.ceil(total / num_arms)
            pairs.append({"levels": [a, b], "pilot_participants": len(both), "sd": spread, "effect_size": effect,
                          "participants": per_arm * num_arms, "per_arm": per_arm, "needed": total})
        else:
            groups = [means[level].dropna() if level in means else pd.Series(dtype=float) for level in (a, b)]
            sds = [_spread(g, f"{factor} = {level!r}, between participants") for g, level in zip(groups, (a, b))]
            pooled = math.sqrt(((len(groups[0]) - 1) * sds[0] ** 2 + (len(groups[1]) - 1) * sds[1] ** 2)
                               / (len(groups[0]) + len(groups[1]) - 2))
            effect = comparison.difference / pooled
            group = participants_needed(effect, comparison.alpha, comparison.power, paired=False)
            conditions = max(sum(getattr(c, factor) == level for c in study.conditions) for level in (a, b))
            per_arm = math.ceil(group / conditions)
            pairs.append({"levels": [a, b], "pilot_participants": int(sum(len(g) for g in groups)), "sd": pooled,
                          "effect_size": effect, "per_group": group, "per_arm": per_arm,
                          "participants": per_arm * num_arms, "needed": group})
    hardest = max(pairs, key=lambda p: p["per_arm"])
    return {"study": study.id, "design": study.design.assignment, "measure": comparison.measure, "factor": factor,
            "difference": comparison.difference, "power": comparison.power, "alpha": comparison.alpha,
            "arms": num_arms, "quota": study.design.quota, "pairs": pairs, "per_arm": hardest["per_arm"],
            "participants": hardest["participants"]}


def t_test_power(effect: float, n: int, alpha: float, paired: bool) -> float:
    """The power of the two-sided t-test at ``alpha`` to find a standardized difference ``effect``: paired (one
    sample of ``n`` differences, ``d_z``) or two equal groups of ``n`` (Cohen's ``d``). The noncentral t's tail,
    integrated over the spread's chi-square (quantile by quantile), which stays exact where scipy's and statsmodels'
    noncentral t lose their way (one or two degrees of freedom and a large effect). The integrand calls the special
    functions that ``stats.chi2.ppf``, ``stats.norm.sf`` and ``stats.norm.cdf`` compute with, without their argument
    checks: the same numbers, about seventy times sooner (``participants_needed`` asks for many;
    ``bench/bench_study_power.py`` times both)."""
    from scipy import integrate, special, stats

    df = n - 1 if paired else 2 * n - 2
    shift = effect * math.sqrt(n if paired else n / 2)
    critical = stats.t.ppf(1 - alpha / 2, df)

    def rejected(u: float) -> float:  # P(|t| > critical) given the spread's chi-square at its quantile u
        scale = critical * math.sqrt(2 * special.gammaincinv(df / 2, u) / df)  # (chi2.ppf(u, df) = 2 gammaincinv)
        return special.ndtr(shift - scale) + special.ndtr(-scale - shift)  # (norm.sf(scale - shift) + norm.cdf)

    return float(integrate.quad(rejected, 0.0, 1.0, limit=200)[0])


def participants_needed(effect: float, alpha: float, power: float, paired: bool) -> int:
    """The fewest participants (paired: in all; two groups: in each) whose t-test has at least ``power``
    (``t_test_power``, which grows with them): G*Power's answer, and statsmodels' ``solve_power`` rounded up where
    that converges; its solver fails, or stops short, for a large effect and a handful of participants."""
    def enough(n: int) -> bool:
        return t_test_power(effect, n, alpha, paired) >= power

    high = 2
    while not enough(high):
        if high > 10**8:
            raise ValueError(f"an effect size of {effect:.3g} needs more than 10^8 participants: plan on a larger "
                             "difference")
        high *= 2
    low = max(2, high // 2)
    if enough(low):
        return low
    while high - low > 1:  # enough(high), not enough(low)
        middle = (low + high) // 2
        low, high = (low, middle) if enough(middle) else (middle, high)
    return high


def _spread(values: pd.Series, what: str) -> float:
    values = np.asarray(values, dtype=np.float64)
    if len(values) < 2:
        raise ValueError(f"the pilot has {len(values)} participant(s) for {what}: a spread needs 2 or more")
    sd = float(np.std(values, ddof=1))
    if not sd > 0:
        raise ValueError(f"the pilot's {len(values)} participants do not vary for {what} (sd 0): no effect size to "
                         "plan on; pilot more participants or another measure")
    return sd


def format_power(report: dict) -> str:
    """The sample size in words: the trials left out as excluded (where ``report`` says, as ``left_out``), per pair of
    levels, then what an arm of the study needs."""
    within = report["design"] == "within"
    lines = [f"{report['study']}: {report['measure']}, {report['factor']}'s levels compared "
             f"({'within participants: paired t-test' if within else 'between participants: two-sample t-test'}, "
             f"two-sided, alpha {report['alpha']:g}, power {report['power']:.0%}), to find a difference of "
             f"{report['difference']:g}"]
    if "left_out" in report:
        lines.append(format_left_out(report["left_out"]))
    for pair in report["pairs"]:
        a, b = pair["levels"]
        if within:
            lines.append(f"  {a} vs {b}: sd of the per-participant differences {pair['sd']:.4g} over "
                         f"{pair['pilot_participants']} pilot participants, d_z {pair['effect_size']:.3f}: "
                         f"{pair['needed']} participants, {pair['per_arm']} per arm over {report['arms']} arm(s)")
        else:
            lines.append(f"  {a} vs {b}: pooled sd {pair['sd']:.4g} over {pair['pilot_participants']} pilot "
                         f"participants, d {pair['effect_size']:.3f}: {pair['needed']} per level, "
                         f"{pair['per_arm']} per arm")
    lines.append(f"an arm needs {report['per_arm']} participants ({report['participants']} in all over "
                 f"{report['arms']} arm(s))")
    if report["quota"] is not None:
        enough = "enough" if report["quota"] >= report["per_arm"] else "too few"
        lines.append(f"the study's quota is {report['quota']} per arm ({report['quota'] * report['arms']} in all): "
                     f"{enough}")
    return "\n".join(lines)


def format_left_out(left_out: dict | None) -> str:
    """What ``drop_excluded`` left out, in words, by rule (None: the excluded were kept)."""
    if left_out is None:
        return "the excluded trials kept (--keep-excluded): every counted trial of the pilot"
    where = "left out as excluded (the pilot's exclusions table; --keep-excluded keeps them)"
    if not left_out["trials"]:
        return f"{where}: none of its {left_out['of']} trials"
    parts = []
    if left_out["participants"]:
        parts.append(f"the {left_out['participant_trials']} trial(s) of {left_out['participants']} participant(s) "
                     f"excluded as a whole ({_by_rule(left_out['participant_rules'])})")
    if left_out["excluded_trials"]:
        parts.append(f"{left_out['excluded_trials']} trial(s) excluded on their own "
                     f"({_by_rule(left_out['trial_rules'])})")
    return f"{where}: {left_out['trials']} of its {left_out['of']} trials: {' and '.join(parts)}"


def _by_rule(counts: dict[str, int]) -> str:
    return ", ".join(f"{rule} {n}" for rule, n in counts.items())
