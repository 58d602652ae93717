"""The statistics a claim's verdict and the measures beside it are made of, each a small function over per-seed
finals: the test (Welch's, paired by seed, or one-sample against a threshold) with its interval at the claim's
level, Holm's adjustment across a family of claims, the power of the test (statsmodels), the interquartile mean
with a stratified bootstrap interval and the probability of improvement (rliable's measures, computed with scipy),
and whether a team is a single-agent solution. ``train.sweep.claims`` puts them together; docs/SWEEPS.md says
why each is there. Every function is checked against a known answer in tests/test_claim_stats.py."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from enum import Enum
from functools import partial

import numpy as np

POWER = 0.8
"""The power the seeds a claim needs are computed for."""
MOST_SEEDS = 1000
"""Seeds a configuration beyond which the count is printed as ``> 1000`` (a difference too small to chase)."""
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0
"""The bootstrap's resamples are drawn from a fixed seed, so a report recomputes to the same digits."""
MEASURE_CONFIDENCE = 0.95
"""The level of the interquartile means' bootstrap intervals (descriptive, beside the test)."""


class Comparison(str, Enum):
    """How a claim's two sides are compared."""

    WELCH = "Welch"
    """Two configurations, trained apart: Welch's two-sample t-test."""
    PAIRED = "paired"
    """A configuration against a baseline evaluated on each seed's own evaluation seeds: the t-test of the
    per-seed differences (scipy's ``ttest_rel``)."""
    ONE_SAMPLE = "one-sample"
    """A configuration against a true threshold (a constant): the one-sample t-test."""


@dataclass(frozen=True)
class Test:
    """A test's result: the difference of means ``a - b``, its two-sided interval at ``confidence``, and p."""

    difference: float
    low: float
    high: float
    p: float
    p_equivalence: float = math.nan
    """``~`` only: the larger p of two one-sided tests against ``-margin`` and ``+margin`` (TOST): below alpha
    exactly when the ``1 - 2 alpha`` interval lies within the margin."""
    p_outside: float = math.nan
    """``~`` only: the smaller p of the one-sided tests that the difference lies above ``+margin`` or below
    ``-margin``: below alpha exactly when the ``1 - 2 alpha`` interval lies wholly outside the margin."""


def t_test(kind: Comparison, a, b, confidence: float, margin: float = 0.0) -> Test:
    """Test ``a`` (per-seed finals) against ``b``: finals of another configuration (``WELCH``), the baseline's
    finals on the same seeds in the same order (``PAIRED``), or a constant (``ONE_SAMPLE``). The interval is two-sided
    at ``confidence``; with ``margin`` > 0 the TOST p of equivalence within it, and the p of a difference beyond
    it, too. Sides without spread give NaN."""
    from scipy import stats

    a = np.asarray(a, dtype=float)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        if kind is Comparison.ONE_SAMPLE:
            b = float(b)
            test = stats.ttest_1samp(a, b)
            tails = (stats.ttest_1samp(a, b - margin, alternative="greater"),
                     stats.ttest_1samp(a, b + margin, alternative="less"))
            beyond = (stats.ttest_1samp(a, b + margin, alternative="greater"),
                      stats.ttest_1samp(a, b - margin, alternative="less"))
            shift = b  # scipy's interval is of a's mean: made one of the difference
        else:
            b = np.asarray(b, dtype=float)
            two = stats.ttest_rel if kind is Comparison.PAIRED else partial(stats.ttest_ind, equal_var=False)
            test = two(a, b)
            tails = (two(a, b - margin, alternative="greater"), two(a, b + margin, alternative="less"))
            beyond = (two(a, b + margin, alternative="greater"), two(a, b - margin, alternative="less"))
            shift = 0.0
        interval = test.confidence_interval(confidence)
        p_eq = float(max(t.pvalue for t in tails)) if margin > 0 else math.nan
        p_out = float(min(t.pvalue for t in beyond)) if margin > 0 else math.nan
    return Test(float(a.mean() - np.mean(b)), float(interval.low - shift), float(interval.high - shift),
                float(test.pvalue), p_eq, p_out)


def holm(p_values) -> list[float]:
    """Holm's step-down adjustment of a family's p-values (statsmodels' ``multipletests``); a NaN (a claim without
    a test) stays NaN and is not counted in the family."""
    from statsmodels.stats.multitest import multipletests

    p = np.asarray(p_values, dtype=float)
    out = np.full(len(p), math.nan)
    tested = np.isfinite(p)
    if tested.any():
        out[tested] = multipletests(p[tested], method="holm")[1]
    return [float(v) for v in out]


@dataclass(frozen=True)
class Power:
    """What the test could see: its power now at the observed difference and spread, the seeds a configuration
    would need for ``POWER``, and the smallest difference the current seeds detect with ``POWER`` (in the
    column's units)."""

    now: float = math.nan
    seeds: float = math.nan
    """Seeds a configuration (per side; for a paired or one-sample test, pairs or seeds); ``inf`` beyond
    ``MOST_SEEDS``."""
    detectable: float = math.nan


def power(kind: Comparison, a, b, difference: float, alpha: float, margin: float = 0.0) -> Power:
    """The power of the claim's test (statsmodels' ``TTestIndPower`` for Welch's, with Cohen's d over the two
    sides' root mean variance, ``TTestPower`` over the per-seed differences or the seeds against a threshold),
    two-sided at ``alpha``. For a claim of no difference (``margin`` > 0), the power of showing the observed
    difference within the margin, one-sided against the nearer bound (the far one ignored: a little optimistic),
    and no smallest difference."""
    from statsmodels.stats.power import TTestIndPower, TTestPower

    a = np.asarray(a, dtype=float)
    if kind is Comparison.WELCH:
        b = np.asarray(b, dtype=float)
        if len(a) < 2 or len(b) < 2:
            return Power()
        spread = math.sqrt((a.var(ddof=1) + b.var(ddof=1)) / 2)
        analysis, nobs, extra = TTestIndPower(), len(a), {"ratio": len(b) / len(a)}
        needs = {"ratio": 1.0}
    else:
        values = a - np.asarray(b, dtype=float) if kind is Comparison.PAIRED else a
        if len(values) < 2:
            return Power()
        spread = float(values.std(ddof=1))
        analysis, nobs, extra, needs = TTestPower(), len(values), {}, {}
    if not math.isfinite(difference) or not spread > 0:
        return Power()
    if margin > 0:
        effect, alternative = (margin - abs(difference)) / spread, "larger"
        if effect <= 0:
            return Power(now=0.0, seeds=math.inf)
    else:
        effect, alternative = abs(difference) / spread, "two-sided"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        now = float(analysis.power(effect, nobs, alpha, alternative=alternative, **extra))
        seeds = _seeds_needed(analysis, effect, alpha, alternative, needs)
        detectable = math.nan
        if margin <= 0:
            detectable = float(analysis.solve_power(None, nobs, alpha, POWER, alternative=alternative,
                                                    **extra)) * spread
    now = 1.0 if not math.isfinite(now) and effect > 10 else now  # statsmodels' NaN far out in the tail
    return Power(now, seeds, detectable)


def _seeds_needed(analysis, effect: float, alpha: float, alternative: str, extra: dict) -> float:
    """The smallest whole number of seeds (at least 2) with power ``POWER``: ``inf`` beyond ``MOST_SEEDS``."""
    def enough(n: int) -> bool:  # statsmodels gives NaN where the power rounds to 1
        return not analysis.power(effect, n, alpha, alternative=alternative, **extra) < POWER

    if effect <= 0 or not enough(MOST_SEEDS):
        return math.inf
    low, high = 1, MOST_SEEDS  # power grows with the seeds: the first n where it reaches POWER, by bisection
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (low, middle) if enough(middle) else (middle, high)
    return float(max(2, high))


def iqm(values) -> float:
    """The interquartile mean: the mean of the middle half (scipy's ``trim_mean`` cutting a quarter each side, as
    rliable's ``aggregate_iqm``)."""
    from scipy import stats

    values = np.asarray(values, dtype=float)
    return float(stats.trim_mean(values, 0.25)) if len(values) else math.nan


def iqm_interval(strata) -> tuple[float, float, float]:
    """The interquartile mean of a side pooled over its ``strata`` (one list of finals per configuration) and its
    ``MEASURE_CONFIDENCE`` percentile interval from a stratified bootstrap (each configuration's seeds resampled
    within it, scipy's ``bootstrap`` over the strata as separate samples, as rliable's
    ``StratifiedBootstrap``). A side with fewer than two finals, or without spread, has no interval."""
    from scipy import stats

    strata = [np.asarray(s, dtype=float) for s in strata if len(s)]
    pooled = np.concatenate(strata) if strata else np.array([])
    estimate = iqm(pooled)
    if len(pooled) < 2 or np.ptp(pooled) == 0 or any(len(s) < 2 for s in strata):
        return estimate, math.nan, math.nan

    def statistic(*samples, axis=-1):
        return stats.trim_mean(np.concatenate(samples, axis=axis), 0.25, axis=axis)

    result = stats.bootstrap(tuple(strata), statistic, n_resamples=BOOTSTRAP_RESAMPLES, vectorized=True,
                             paired=False, confidence_level=MEASURE_CONFIDENCE, method="percentile",
                             rng=np.random.default_rng(BOOTSTRAP_SEED))
    return estimate, float(result.confidence_interval.low), float(result.confidence_interval.high)


def probability_of_improvement(a, b) -> float:
    """P(a > b): the chance a seed of side ``a`` ends above one of side ``b`` (ties count a half), the Mann-Whitney
    U of ``a`` over the pairs (rliable's ``probability_of_improvement``); against a constant, the share of ``a``'s
    seeds above it."""
    from scipy import stats

    a = np.asarray(a, dtype=float)
    if not len(a):
        return math.nan
    if np.ndim(b) == 0:
        return float(np.mean(a > b) + 0.5 * np.mean(a == b))
    b = np.asarray(b, dtype=float)
    if not len(b):
        return math.nan
    return float(stats.mannwhitneyu(a, b).statistic / (len(a) * len(b)))


def single_agent(one: float, other: float) -> bool:
    """Whether a team is a single-agent solution: one agent collects at least twice the other's net pickups (an
    agent at or below zero against one above it counts), the rule docs/REPRODUCTION.md counts by."""
    high, low = max(one, other), min(one, other)
    return high > 0 and high >= 2 * low
