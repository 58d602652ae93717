"""A sweep's claims, and the verdict on each computed from its trials' finals (docs/SWEEPS.md, "Claims").

A claim (declared in a sweep file: ``train.sweep.claim_spec``) compares two sides of a sweep on one final column (the sweep's metric by default): side ``a``
is a configuration (``{parameter: value}``; a parameter left out, or given a list of values, pools
the seeds of every matching configuration), side ``b`` another, or a constant (a baseline's score).
The paper's direction is ``a > b``, ``a < b``, or ``a ~ b`` (no difference beyond ``margin``, in the
column's units). Each side's values are the per-seed finals of its finished trials.

The statistics are scipy's: Welch's t-test (two-sided) and its 95% interval for the difference of
means, or the one-sample t-test against a constant; for ``~``, two one-sided tests (TOST) against
``-margin`` and ``+margin``. The verdict, by one rule (``verdict``):

* ``>`` or ``<``: **reproduced** if the difference has the paper's sign and p < 0.05; **in direction
  only** if it has the paper's sign and p >= 0.05; **not reproduced** if it has the opposite sign and
  p < 0.05; **inconclusive** otherwise.
* ``~``: **reproduced** if the TOST p < 0.05 (the difference is shown to lie within the margin);
  **in direction only** if the difference of means lies within the margin without that; **not
  reproduced** if it lies outside and Welch's p < 0.05; **inconclusive** otherwise.

A side with fewer than two finished seeds, or two sides without spread, gives no p-value and is
inconclusive.

A claim tested more than once is held to a stricter level. Seeds a ``[[more_seeds]]`` table adds to a
configuration of a claim's side are there because the first seeds had not decided it, so the claim is tested
once on ``seeds`` and again with each such round of seeds (``count_looks``), and at 0.05 each time it would come
out reproduced wrongly more often than 5% of the time. Every 0.05 above is then 0.05 divided by the looks
(Bonferroni's correction, ``level``): it holds whatever the number of seeds each look adds, where Pocock's
boundaries (0.0294 a look for two) assume equal steps. Seeds every configuration gets whatever the first ones
said go in ``seeds`` and cost no look. The interval stays at 95% whatever the level.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from enum import Enum

import numpy as np
import pandas as pd

from train.sweep.claim_spec import Claim, Direction, matches

ALPHA = 0.05
"""The significance level of a verdict on a claim tested once (``level``)."""


class Verdict(str, Enum):
    REPRODUCED = "reproduced"
    IN_DIRECTION = "in direction only"
    NOT_REPRODUCED = "not reproduced"
    INCONCLUSIVE = "inconclusive"


def side_values(trials: pd.DataFrame, side: dict, column: str) -> list[float]:
    """The finals of ``column`` of the finished trials of a configuration side, in seed order."""
    if trials.empty or column not in trials.columns:
        return []
    rows = trials[trials["finished"].astype(bool)]
    keep = [matches(side, row) for _, row in rows.iterrows()]
    chosen = rows[keep].sort_values(["seed"] + (["configuration"] if "configuration" in rows else []))
    return [float(v) for v in chosen[column] if math.isfinite(v)]


@dataclass(frozen=True)
class Outcome:
    """A claim decided: each side's values, the difference of means with its 95% interval, p and the verdict."""

    claim: Claim
    a: list[float]
    b: list[float] | float
    difference: float
    low: float
    high: float
    p: float
    p_equivalence: float
    verdict: Verdict
    looks: int = 1
    """How many times the claim is tested (``count_looks``); its verdict is at ``level(looks)``."""

    @property
    def mean_a(self) -> float:
        return float(np.mean(self.a)) if self.a else math.nan

    @property
    def mean_b(self) -> float:
        if isinstance(self.b, float):
            return self.b
        return float(np.mean(self.b)) if self.b else math.nan


def count_looks(spec, claim: Claim) -> int:
    """How many times ``claim`` is tested: once on the sweep's ``seeds``, and once more for each set of seeds that
    ``[[more_seeds]]`` tables give a configuration on either of its sides (tables with the same seeds, one for each
    side, are one round; the module docstring says why). The looks are those the file plans: a table whose trials
    have not run yet counts already, so the level does not change as they finish."""
    sides = [side for side in (claim.a, claim.b) if isinstance(side, dict)]
    compared = [c for c in spec.configurations() if any(matches(side, c) for side in sides)]
    rounds = {tuple(sorted(more.seeds)) for more in spec.more_seeds if any(matches(more.where, c) for c in compared)}
    return 1 + len(rounds)


def level(looks: int = 1) -> float:
    """The significance level of each test of a claim tested ``looks`` times: ``ALPHA / looks`` (Bonferroni)."""
    return ALPHA / looks


def verdict(direction: Direction, difference: float, p: float, p_equivalence: float = math.nan,
            margin: float = 0.0, alpha: float = ALPHA) -> Verdict:
    """The one rule (module docstring): the verdict from the difference of means (a - b) and the p-values, at
    significance level ``alpha`` (``level``)."""
    if not math.isfinite(difference):
        return Verdict.INCONCLUSIVE
    if direction is Direction.SAME:
        if math.isfinite(p_equivalence) and p_equivalence < alpha:
            return Verdict.REPRODUCED
        if abs(difference) <= margin:
            return Verdict.IN_DIRECTION
        return Verdict.NOT_REPRODUCED if math.isfinite(p) and p < alpha else Verdict.INCONCLUSIVE
    agrees = difference > 0 if direction is Direction.GREATER else difference < 0
    if not math.isfinite(p):
        return Verdict.INCONCLUSIVE
    if agrees:
        return Verdict.REPRODUCED if p < alpha else Verdict.IN_DIRECTION
    return Verdict.NOT_REPRODUCED if p < alpha else Verdict.INCONCLUSIVE


def decide(claim: Claim, a: list[float], b: list[float] | float, looks: int = 1) -> Outcome:
    """Test ``a`` against ``b`` (values, or a constant) as the claim says, and give the verdict at the level of a
    claim tested ``looks`` times."""
    from scipy import stats

    nan = math.nan
    difference = low = high = p = p_eq = nan
    a_arr = np.asarray(a, dtype=float)
    constant = isinstance(b, float)
    b_arr = None if constant else np.asarray(b, dtype=float)
    if len(a_arr) and (constant or len(b_arr)):
        difference = float(a_arr.mean() - (b if constant else b_arr.mean()))
    enough = len(a_arr) >= 2 and (constant or len(b_arr) >= 2)
    if enough:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            if constant:
                test = stats.ttest_1samp(a_arr, b)
                interval = test.confidence_interval(0.95)
                low, high = interval.low - b, interval.high - b
            else:
                test = stats.ttest_ind(a_arr, b_arr, equal_var=False)
                interval = test.confidence_interval(0.95)
                low, high = interval.low, interval.high
            p = float(test.pvalue)
            if claim.direction is Direction.SAME:
                m = claim.margin
                if constant:
                    above = stats.ttest_1samp(a_arr, b - m, alternative="greater").pvalue
                    below = stats.ttest_1samp(a_arr, b + m, alternative="less").pvalue
                else:
                    above = stats.ttest_ind(a_arr, b_arr - m, equal_var=False, alternative="greater").pvalue
                    below = stats.ttest_ind(a_arr, b_arr + m, equal_var=False, alternative="less").pvalue
                p_eq = float(max(above, below))
    if not enough:
        return Outcome(claim, list(a), b if constant else list(b), difference, nan, nan, nan, nan,
                       Verdict.INCONCLUSIVE, looks)
    return Outcome(claim, list(a), b if constant else list(b), difference, float(low), float(high), p, p_eq,
                   verdict(claim.direction, difference, p, p_eq, claim.margin, level(looks)), looks)


def evaluate(spec, trials: pd.DataFrame) -> list[Outcome]:
    """Every claim of ``spec`` decided on the ``trials`` table (its ``final_<metric>`` columns)."""
    outcomes = []
    for claim in spec.claims:
        column = f"final_{claim.metric}"
        a = side_values(trials, claim.a, column)
        b = claim.b if isinstance(claim.b, float) else side_values(trials, claim.b, column)
        outcomes.append(decide(claim, a, b, count_looks(spec, claim)))
    return outcomes


def table(outcomes: list[Outcome]) -> pd.DataFrame:
    """The decided claims as a tidy table (``claims.csv``)."""
    rows = []
    for o in outcomes:
        c = o.claim
        rows.append({
            "claim": c.name, "paper": c.paper, "metric": c.metric, "expect": c.direction.value, "margin": c.margin,
            "a": c.side_name(c.a), "b": c.side_name(c.b, c.b_name), "n_a": len(o.a),
            "n_b": 0 if isinstance(o.b, float) else len(o.b), "mean_a": o.mean_a, "mean_b": o.mean_b,
            "a_values": " ".join(f"{v:.3f}" for v in o.a),
            "b_values": "" if isinstance(o.b, float) else " ".join(f"{v:.3f}" for v in o.b),
            "difference": o.difference, "ci95_low": o.low, "ci95_high": o.high, "p": o.p,
            "p_equivalence": o.p_equivalence, "looks": o.looks, "level": level(o.looks), "verdict": o.verdict.value})
    return pd.DataFrame(rows)


def format_claims(outcomes: list[Outcome]) -> str:
    """The claims as Markdown: a table of verdicts, then each side's per-seed finals."""
    if not outcomes:
        return ""
    head = ["claim", "the paper", "a", "b", "a - b (95% CI)", "p", "verdict"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for o in outcomes:
        c = o.claim
        shown_b = c.side_name(c.b, c.b_name)
        diff = "-" if not math.isfinite(o.difference) else (
            f"{o.difference:+.2f}" + (f" [{o.low:+.2f}, {o.high:+.2f}]" if math.isfinite(o.low) else ""))
        p = "-" if not math.isfinite(o.p) else f"{o.p:.3g}"
        if c.direction is Direction.SAME:
            p += f"; within ±{c.margin:g}: " + ("-" if not math.isfinite(o.p_equivalence) else f"{o.p_equivalence:.3g}")
        if o.looks > 1 and math.isfinite(o.p):
            p += f" (level {level(o.looks):.3g}: {o.looks} looks)"
        lines.append("| " + " | ".join([
            f"{c.name} (a {c.direction.value} b{', ' + c.metric if c.metric else ''})", c.paper,
            f"{c.side_name(c.a)}: {_mean(o.mean_a)} (n={len(o.a)})",
            f"{shown_b}: {_mean(o.mean_b)}" + ("" if isinstance(o.b, float) else f" (n={len(o.b)})"),
            diff, p, f"**{o.verdict.value}**"]) + " |")
    lines += ["", "Per-seed finals:", ""]
    for o in outcomes:
        b = "" if isinstance(o.b, float) else f"; b: {', '.join(f'{v:+.2f}' for v in o.b) or 'none finished'}"
        lines.append(f"- {o.claim.name}: a: {', '.join(f'{v:+.2f}' for v in o.a) or 'none finished'}{b}")
    return "\n".join(lines)


def _mean(value: float) -> str:
    """A side's mean as the table shows it: ``-`` for a side with no finished trial yet."""
    return f"{value:+.2f}" if math.isfinite(value) else "-"
