"""The decided claims as the report shows them: a tidy table (``claims.csv``) and Markdown (``report.md``): the
verdicts with the test's figures, then the measures beside the test, then each side's per-seed finals."""

from __future__ import annotations

import math

import pandas as pd

from train.sweep.claim_spec import Direction
from train.sweep.claim_stats import MEASURE_CONFIDENCE, MOST_SEEDS, POWER
from train.sweep.claims import Outcome, Verdict


def table(outcomes: list[Outcome]) -> pd.DataFrame:
    """The decided claims as a tidy table (``claims.csv``): the interval is at ``ci_level`` (1 - the claim's level;
    1 - twice it for ``~``), ``p`` is the test's own, ``p_equivalence`` and ``p_outside`` a ``~`` claim's within and
    beyond the margin, ``p_adjusted`` Holm's across the file's claims (what the verdict reads), and ``declared``
    whether the claim was declared before its data (``train.sweep.declared``; after: the verdict is exploratory)."""
    rows = []
    for o in outcomes:
        c = o.claim
        rows.append({
            "claim": c.name, "paper": c.paper, "metric": c.metric, "expect": c.direction.value, "margin": c.margin,
            "a": c.side_name(c.a), "b": c.side_name(c.b, c.b_name), "test": o.kind.value, "n_a": len(o.a),
            "n_b": 0 if isinstance(o.b, float) else len(o.b), "mean_a": o.mean_a, "mean_b": o.mean_b,
            "seeds_a": " ".join(map(str, o.seeds_a)), "seeds_b": " ".join(map(str, o.seeds_b)),
            "a_values": " ".join(f"{v:.3f}" for v in o.a),
            "b_values": "" if isinstance(o.b, float) else " ".join(f"{v:.3f}" for v in o.b),
            "difference": o.difference, "ci_level": o.confidence, "ci_low": o.low, "ci_high": o.high, "p": o.p,
            "p_equivalence": o.p_equivalence, "p_outside": o.p_outside, "p_adjusted": o.p_adjusted, "looks": o.looks, "level": o.level,
            "power": o.power.now, "seeds_for_power": o.power.seeds, "detectable_difference": o.power.detectable,
            "iqm_a": o.iqm_a[0], "iqm_a_low": o.iqm_a[1], "iqm_a_high": o.iqm_a[2],
            "iqm_b": o.iqm_b[0], "iqm_b_low": o.iqm_b[1], "iqm_b_high": o.iqm_b[2],
            "p_improvement": o.p_improvement, "single_agent_a": o.single_a, "single_agent_b": o.single_b,
            "declared": o.declared.value, "verdict": o.verdict.value})
    return pd.DataFrame(rows)


def undecided(o: Outcome) -> bool:
    return o.verdict in (Verdict.IN_DIRECTION, Verdict.INCONCLUSIVE, Verdict.EXPLORATORY)


def format_claims(outcomes: list[Outcome]) -> str:
    """The claims as Markdown: the verdicts, the measures beside them, and each side's per-seed finals."""
    if not outcomes:
        return ""
    head = ["claim", "the paper", "a", "b", "test", "a - b [interval at the claim's level]", "p", "Holm p", "level",
            "declared", "verdict"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for o in outcomes:
        c = o.claim
        shown_b = c.side_name(c.b, c.b_name)
        diff = "-" if not math.isfinite(o.difference) else (
            f"{o.difference:+.2f}" + (f" [{o.low:+.2f}, {o.high:+.2f}] ({100 * o.confidence:.4g}%)"
                                      if math.isfinite(o.low) else ""))
        p = _p(o.p)
        if c.direction is Direction.SAME:
            p += f"; within ±{c.margin:g}: {_p(o.p_equivalence)}; beyond ±{c.margin:g}: {_p(o.p_outside)}"
        shown_level = f"{o.level:.3g}" + (f" ({o.looks} looks)" if o.looks > 1 else "")
        lines.append("| " + " | ".join([
            f"{c.name} (a {c.direction.value} b{', ' + c.metric if c.metric else ''})", c.paper,
            f"{c.side_name(c.a)}: {_mean(o.mean_a)} (n={len(o.a)})",
            f"{shown_b}: {_mean(o.mean_b)}" + ("" if isinstance(o.b, float) else f" (n={len(o.b)})"),
            o.kind.value, diff, p, _p(o.p_adjusted), shown_level, o.declared.value,
            f"**{o.verdict.value}**"]) + " |")
    lines += ["", f"Beside the test: each side's interquartile mean with its {MEASURE_CONFIDENCE:.0%} stratified "
                  f"bootstrap interval, the probability of improvement P(a > b), the single-agent solutions among "
                  f"each side's trials (one agent with at least twice the other's net pickups), and for each claim "
                  f"not decided the test's power now, the seeds a configuration would need for {POWER:.0%} power at "
                  f"the observed difference and spread, and the smallest difference the current seeds detect with "
                  f"{POWER:.0%} power, at the claim's level.", ""]
    head = ["claim", "IQM a", "IQM b", "P(a > b)", "single-agent a, b", "power", f"seeds for {POWER:.0%}",
            "detectable a - b"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for o in outcomes:
        open_ = undecided(o)
        lines.append("| " + " | ".join([
            o.claim.name, _iqm(o.iqm_a), _iqm(o.iqm_b),
            "-" if not math.isfinite(o.p_improvement) else f"{o.p_improvement:.2f}",
            f"{_count(o.single_a, len(o.a))}, {_count(o.single_b, 0 if isinstance(o.b, float) else len(o.b))}",
            _fraction(o.power.now) if open_ else "-", _seeds(o.power.seeds) if open_ else "-",
            _signed(o.power.detectable) if open_ else "-"]) + " |")
    lines += ["", "Per-seed finals:", ""]
    for o in outcomes:
        b = "" if isinstance(o.b, float) else f"; b: {', '.join(f'{v:+.2f}' for v in o.b) or 'none finished'}"
        lines.append(f"- {o.claim.name}: a: {', '.join(f'{v:+.2f}' for v in o.a) or 'none finished'}{b}")
    return "\n".join(lines)


def _p(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{value:.3g}"


def _mean(value: float) -> str:
    """A side's mean as the table shows it: ``-`` for a side with no finished trial yet."""
    return f"{value:+.2f}" if math.isfinite(value) else "-"


def _iqm(measure: tuple[float, float, float]) -> str:
    estimate, low, high = measure
    if not math.isfinite(estimate):
        return "-"
    return f"{estimate:+.2f}" + (f" [{low:+.2f}, {high:+.2f}]" if math.isfinite(low) else "")


def _count(count: int | None, of: int) -> str:
    return "-" if count is None or not of else f"{count} of {of}"


def _fraction(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{value:.2f}"


def _seeds(value: float) -> str:
    if math.isinf(value):
        return f"> {MOST_SEEDS}"
    return "-" if not math.isfinite(value) else f"{value:.0f}"


def _signed(value: float) -> str:
    return "-" if not math.isfinite(value) else f"±{value:.2f}"
