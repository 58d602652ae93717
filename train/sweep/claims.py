"""A sweep's claims, and the verdict on each computed from its trials' finals (docs/SWEEPS.md, "Claims").

A claim (declared in a sweep file: ``train.sweep.claim_spec``) compares two sides of a sweep on one final column
(the sweep's metric by default): side ``a`` is a configuration (``{parameter: value}``; a parameter left out, or
given a list of values, pools the seeds of every matching configuration), side ``b`` another, a baseline's per-seed
figures (``train.sweep.baselines``), or a constant (a true threshold, such as 0). The paper's direction is ``a > b``,
``a < b``, or ``a ~ b`` (no difference beyond ``margin``, in the column's units).

The test (``claim_stats.t_test``, scipy's): Welch's two-sided t-test between configurations; against a baseline,
the t-test of the per-seed differences, paired by seed (the baseline played the arm's own evaluation episodes,
so the seed-to-seed spread they share cancels); against a threshold, the one-sample t-test; for ``~``, two
one-sided tests (TOST) against ``-margin`` and ``+margin``, and the one-sided test that the difference lies beyond
the margin. The interval of ``a - b`` is the test's, two-sided at the claim's level: ``1 - level``; for ``~``,
``1 - 2 level``, the interval the two one-sided tests read (TOST at ``level`` shows equivalence exactly when it lies
within the margin, and the test beyond the margin a difference exactly when it lies wholly outside).

A file's claims are one family: read at 0.05 each, a file of 12 claims would call one reproduced wrongly far more
often than 5% of the time. Each claim's p (``Outcome.decisive_p``) is adjusted by Holm's step-down method across the
family, which holds the chance of any wrong verdict in the file at the level, and the verdict reads the adjusted p.
The verdict, by one rule (``verdict``), at the claim's level:

* ``>`` or ``<``: **reproduced** if the difference has the paper's sign and the adjusted p < level; **in direction
  only** if it has the paper's sign without that (undecided: the report prints its power and the seeds it needs);
  **not reproduced** if it has the opposite sign and the adjusted p < level; **inconclusive** otherwise.
* ``~``: **reproduced** if the difference lies within the margin and the adjusted TOST p < level; **in direction
  only** if it lies within the margin without that; **not reproduced** if it lies outside and the adjusted p of
  the test beyond the margin < level (the ``1 - 2 level`` interval wholly outside it); **inconclusive** otherwise.

A claim declared, or changed, after trials of its configurations had finished (``train.sweep.declared``) is held as
**exploratory**, whatever its test says: its figures are printed, and it is never called reproduced (nor not
reproduced). It stays in the family, so it makes the other claims' adjusted p no smaller.

A side with fewer than two finished seeds, or two sides without spread, gives no p-value and is inconclusive.

A claim tested more than once is held to a stricter level: ``level`` is 0.05 divided by its looks (Bonferroni's
correction, which holds whatever the number of seeds each look adds, where Pocock's boundaries assume equal steps).
Its looks are counted by ``train.sweep.looks`` from the file's plan and the record of published reports.

Beside the test, for each claim (``claim_stats``): its power at the observed difference and spread, the seeds a
configuration needs for 80% power and the smallest difference the current seeds detect; each side's interquartile
mean with a stratified bootstrap interval and the probability of improvement (rliable's measures: finals here are
often bimodal); and how many of each side's trials are single-agent solutions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np
import pandas as pd

from train.sweep import claim_stats as st
from train.sweep.baselines import baseline_finals
from train.sweep.claim_spec import Baseline, Claim, Direction, matches
from train.sweep.claim_stats import Power, Test, Comparison
from train.sweep.declared import Declared, read_record, record_folder, status
from train.sweep.looks import count_looks, is_interim, read_history

ALPHA = 0.05
"""The significance level of the family of a file's claims, each tested once (``level``)."""


class Verdict(str, Enum):
    REPRODUCED = "reproduced"
    IN_DIRECTION = "in direction only"
    NOT_REPRODUCED = "not reproduced"
    INCONCLUSIVE = "inconclusive"
    EXPLORATORY = "exploratory"
    """Declared or changed after trials of its configurations finished: printed, never decided."""
    INTERIM = "interim"
    """Its sides have fewer seeds than the look the file plans: printed, decided at the planned look (a verdict
    read on the way would be a look the plan did not make)."""


@dataclass(frozen=True)
class Side:
    """A side's finished trials: each final with its seed and configuration (the bootstrap's stratum), and whether
    the team was a single-agent solution (None where the table lacks either agent's net pickups)."""

    values: tuple[float, ...] = ()
    seeds: tuple[int, ...] = ()
    strata: tuple[str, ...] = ()
    single: tuple[bool, ...] | None = None

    def keep(self, seeds) -> "Side":
        """The trials of these seeds only."""
        chosen = [i for i, s in enumerate(self.seeds) if s in set(seeds)]
        pick = lambda xs: None if xs is None else tuple(xs[i] for i in chosen)  # noqa: E731
        return Side(pick(self.values), pick(self.seeds), pick(self.strata), pick(self.single))

    def by_stratum(self) -> list[list[float]]:
        return [[v for v, s in zip(self.values, self.strata) if s == stratum] for stratum in dict.fromkeys(self.strata)]


def side_finals(trials: pd.DataFrame, side: dict, column: str) -> Side:
    """The finals of ``column`` of the finished trials of a configuration side, in seed order."""
    if trials.empty or column not in trials.columns:
        return Side()
    rows = trials[trials["finished"].astype(bool)]
    keep = [matches(side, row) for _, row in rows.iterrows()]
    chosen = rows[keep].sort_values(["seed"] + (["configuration"] if "configuration" in rows else []))
    chosen = chosen[np.isfinite(chosen[column].astype(float))]
    stream = column[len("final_"):].rpartition("/")[0]
    agents = [f"final_{stream + '/' if stream else ''}{role}_net_pickups" for role in ("leader", "follower")]
    single = None
    if all(c in chosen.columns for c in agents):
        single = tuple(st.single_agent(float(x), float(y)) for x, y in zip(chosen[agents[0]], chosen[agents[1]]))
    strata = chosen["configuration"].astype(str) if "configuration" in chosen else [""] * len(chosen)
    return Side(tuple(float(v) for v in chosen[column]), tuple(int(s) for s in chosen["seed"]), tuple(strata), single)


def side_values(trials: pd.DataFrame, side: dict, column: str) -> list[float]:
    """The finals of ``column`` of the finished trials of a configuration side, in seed order."""
    return list(side_finals(trials, side, column).values)


@dataclass(frozen=True)
class Outcome:
    """A claim decided: each side's finals, the test (difference, its interval at the claim's level, raw p), the
    family's Holm-adjusted p the verdict reads, and the measures beside it."""

    claim: Claim
    a: list[float]
    b: list[float] | float
    kind: Comparison
    test: Test
    verdict: Verdict
    looks: int = 1
    """How many times the claim is tested (``train.sweep.looks``); its verdict is at ``level(looks)``."""
    seeds_a: tuple[int, ...] = ()
    seeds_b: tuple[int, ...] = ()
    p_adjusted: float = math.nan
    """Holm's adjustment of ``decisive_p`` across the file's claims (the family)."""
    power: Power = field(default_factory=Power)
    iqm_a: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    """The interquartile mean of side a with its 95% stratified-bootstrap interval."""
    iqm_b: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    p_improvement: float = math.nan
    """P(a > b) (``claim_stats.probability_of_improvement``)."""
    single_a: int | None = None
    """Single-agent solutions among side a's trials (None where the table lacks the agents' figures)."""
    single_b: int | None = None
    declared: Declared = Declared.UNRECORDED
    """Whether the claim was declared before the data (``train.sweep.declared``)."""
    interim: bool = False
    """Its seeds are not a look the file plans (fewer than the plan asks): the verdict waits (``Verdict.INTERIM``)."""

    difference = property(lambda self: self.test.difference)
    low = property(lambda self: self.test.low)
    high = property(lambda self: self.test.high)
    p = property(lambda self: self.test.p)
    p_equivalence = property(lambda self: self.test.p_equivalence)
    p_outside = property(lambda self: self.test.p_outside)

    @property
    def level(self) -> float:
        return level(self.looks)

    @property
    def confidence(self) -> float:
        """The two-sided level of the printed interval (``confidence``)."""
        return confidence(self.claim, self.looks)

    @property
    def decisive_p(self) -> float:
        """The p the verdict reads before the family's adjustment: the two-sided p for ``>`` and ``<``; for ``~``,
        the TOST p with the difference within the margin, the p of the test beyond the margin outside it."""
        if self.claim.direction is Direction.SAME and math.isfinite(self.difference):
            return self.p_equivalence if abs(self.difference) <= self.claim.margin else self.p_outside
        return self.p

    @property
    def mean_a(self) -> float:
        return float(np.mean(self.a)) if self.a else math.nan

    @property
    def mean_b(self) -> float:
        if isinstance(self.b, float):
            return self.b
        return float(np.mean(self.b)) if self.b else math.nan


def level(looks: int = 1) -> float:
    """The significance level of each test of a claim tested ``looks`` times: ``ALPHA / looks`` (Bonferroni)."""
    return ALPHA / looks


def confidence(claim: Claim, looks: int = 1) -> float:
    """The interval's two-sided level for ``claim`` tested ``looks`` times: ``1 - level``, or ``1 - 2 level`` for
    ``~`` (the interval of the two one-sided tests)."""
    return 1 - (2 if claim.direction is Direction.SAME else 1) * level(looks)


def verdict(direction: Direction, difference: float, p: float, margin: float = 0.0, alpha: float = ALPHA) -> Verdict:
    """The one rule (module docstring): the verdict from the difference of means (a - b) and the p it reads (the
    family-adjusted ``decisive_p``), at significance level ``alpha`` (``level``)."""
    if not math.isfinite(difference) or not math.isfinite(p):
        return Verdict.INCONCLUSIVE
    agrees = {Direction.GREATER: difference > 0, Direction.LESS: difference < 0,
              Direction.SAME: abs(difference) <= margin}[direction]
    if agrees:
        return Verdict.REPRODUCED if p < alpha else Verdict.IN_DIRECTION
    return Verdict.NOT_REPRODUCED if p < alpha else Verdict.INCONCLUSIVE


def decide(claim: Claim, a: Side, b: Side | float, kind: Comparison, looks: int = 1) -> Outcome:
    """Test side ``a`` against ``b`` (a side, or a constant) as the claim says, at the level of a claim tested
    ``looks`` times; the verdict reads the raw p until ``adjust`` gives the family's."""
    constant = isinstance(b, float)
    values_b = b if constant else list(b.values)
    enough = len(a.values) >= 2 and (constant or len(b.values) >= 2)
    if enough:
        test = st.t_test(kind, a.values, values_b, confidence(claim, looks), claim.margin)
    else:
        nan = math.nan
        test = Test(float(np.mean(a.values) - np.mean(values_b)) if a.values and (constant or b.values) else nan,
                    nan, nan, nan)
    chance = st.power(kind, a.values, values_b, test.difference, level(looks), claim.margin) if enough else Power()
    count = lambda side: None if side.single is None else sum(side.single)  # noqa: E731
    outcome = Outcome(
        claim, list(a.values), b if constant else list(b.values), kind, test, Verdict.INCONCLUSIVE, looks,
        a.seeds, () if constant else b.seeds, power=chance, iqm_a=st.iqm_interval(a.by_stratum()),
        iqm_b=(b, math.nan, math.nan) if constant else st.iqm_interval(b.by_stratum()),
        p_improvement=st.probability_of_improvement(a.values, b if constant else values_b),
        single_a=count(a), single_b=None if constant else count(b))
    return adjust(outcome, outcome.decisive_p)


def adjust(outcome: Outcome, p_adjusted: float) -> Outcome:
    """``outcome`` with the family's adjusted p, and the verdict that reads it (exploratory for a claim declared
    after its data)."""
    c = outcome.claim
    decided = verdict(c.direction, outcome.difference, p_adjusted, c.margin, outcome.level)
    if outcome.declared is Declared.AFTER:
        decided = Verdict.EXPLORATORY
    elif outcome.interim:
        decided = Verdict.INTERIM
    return replace(outcome, p_adjusted=p_adjusted, verdict=decided)


def sides(spec, claim: Claim, trials: pd.DataFrame, results) -> tuple[Side, Side | float, Comparison]:
    """The two sides of ``claim`` from the ``trials`` table (and, for a baseline, the ``results`` folder's kept
    figures, paired with side a by seed), and how they are compared."""
    column = f"final_{claim.metric}"
    a = side_finals(trials, claim.a, column)
    if isinstance(claim.b, float):
        return a, claim.b, Comparison.ONE_SAMPLE
    if isinstance(claim.b, Baseline):
        figures = baseline_finals(results, claim.b.name, claim.metric)
        a = a.keep(figures)
        b = Side(tuple(figures[s] for s in a.seeds), a.seeds, ("",) * len(a.seeds))
        return a, b, Comparison.PAIRED
    return a, side_finals(trials, claim.b, column), Comparison.WELCH


def trained_seeds(claim: Claim, trials: pd.DataFrame, a: Side, b: Side | float) -> tuple[tuple, tuple]:
    """The seeds of each side's finished trials, which say whether the file's planned look is reached: ``sides``'s,
    except that a baseline side and side a count side a's trials whether or not the baseline's figures are
    computed yet (``sides`` keeps only the seeds it can pair)."""
    if isinstance(claim.b, Baseline):
        seeds = side_finals(trials, claim.a, f"final_{claim.metric}").seeds
        return seeds, seeds
    return a.seeds, (() if isinstance(b, float) else b.seeds)


def evaluate(spec, trials: pd.DataFrame, history: pd.DataFrame | None = None) -> list[Outcome]:
    """Every claim of ``spec`` decided on the ``trials`` table (its ``final_<metric>`` columns) as one family: each
    claim's looks counted from the file and the record (``history``, by default the results folder's), its p
    adjusted by Holm's method across the file's claims, and each held as exploratory where the record of
    declarations says it came after its data."""
    from train.sweep.results import results_folder

    results = results_folder(spec)
    history = read_history(results) if history is None else history
    declarations = read_record(record_folder(spec))
    outcomes = []
    for claim in spec.claims:
        a, b, kind = sides(spec, claim, trials, results)
        seeds_b = () if isinstance(b, float) else b.seeds
        decided = decide(claim, a, b, kind, count_looks(spec, claim, a.seeds, seeds_b, history))
        outcomes.append(replace(decided, declared=status(spec, claim, trials, declarations),
                                interim=is_interim(spec, claim, *trained_seeds(claim, trials, a, b))))
    adjusted = st.holm([o.decisive_p for o in outcomes])
    return [adjust(o, p) for o, p in zip(outcomes, adjusted)]
