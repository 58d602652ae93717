"""How many times a claim has been looked at, counted from the file's plan and from the record of what each published
report decided (``claims_history.csv``, beside ``claims.csv`` in the results folder, appended by ``sweep publish``
and committed with it).

A look is a test whose verdict could stop the sweep or steer it. The file plans its looks: one on ``seeds``, and one
more for each round of ``[[more_seeds]]`` that reaches a configuration of the claim (tables giving the same seeds are
one round); they count from the moment they are written, before their trials run. The record adds the looks the
plan does not show: a report published on seeds that are the whole plan of their time, or a round of today's file,
is a look, and each different set of seeds such a report decided on is one. A report on fewer seeds than the plan of
its time asked is progress on the way to a look fixed in advance (the first seeds' verdicts could not change which
seeds run), and costs none. A claim's looks are the larger of the two counts (docs/SWEEPS.md, "Looks").
"""

from __future__ import annotations

import datetime
from pathlib import Path

import pandas as pd

from train.sweep.claim_spec import Claim, matches

HISTORY_FILE = "claims_history.csv"
COLUMNS = ("published", "claim", "seeds_a", "seeds_b", "planned_a", "planned_b", "p", "p_adjusted", "level",
           "verdict", "look", "note")


def seeds_text(seeds) -> str:
    """Seeds as the record writes them: sorted, space-separated (``0 1 2``); none: empty."""
    return " ".join(str(s) for s in sorted(int(s) for s in seeds))


def read_seeds(text) -> frozenset[int]:
    return frozenset() if not isinstance(text, str) or not text.strip() else frozenset(int(s) for s in text.split())


def rounds(spec, claim: Claim) -> list[tuple[frozenset[int], frozenset[int]]]:
    """The seeds of each side at each look the file plans: ``seeds``, then ``seeds`` and every round of
    ``[[more_seeds]]`` up to the k-th that reaches the claim's configurations (a side that is not a configuration,
    a baseline paired with side a, takes a's seeds; a constant none)."""
    sides = [claim.a, claim.b]
    reaching = []
    for more in spec.more_seeds:
        chosen = tuple(sorted(more.seeds))
        if chosen not in reaching and any(isinstance(side, dict) and _reaches(spec, more.where, side)
                                          for side in sides):
            reaching.append(chosen)
    out = []
    for k in range(len(reaching) + 1):
        given = {s for chosen in reaching[:k] for s in chosen}
        a = _side_seeds(spec, claim.a, given)
        b = _side_seeds(spec, claim.b, given) if isinstance(claim.b, dict) else (
            frozenset() if isinstance(claim.b, float) else a)
        out.append((a, b))
    return out


def _reaches(spec, where: dict, side: dict) -> bool:
    return any(matches(side, c) and matches(where, c) for c in spec.configurations())


def _side_seeds(spec, side: dict, given: set[int]) -> frozenset[int]:
    """The seeds the configurations of ``side`` train with, of the file's ``seeds`` and the rounds ``given``."""
    seeds = set()
    for values in spec.configurations():
        if matches(side, values):
            seeds |= {s for s in spec.seeds_for(values) if s in spec.seeds or s in given}
    return frozenset(seeds)


def planned_looks(spec, claim: Claim) -> int:
    """The looks the file plans for ``claim``: one on ``seeds`` and one for each round of ``[[more_seeds]]``."""
    return len(rounds(spec, claim))


def is_look(spec, claim: Claim, seeds_a, seeds_b, planned_a=None, planned_b=None) -> bool:
    """Whether a report on these seeds is a look: they are the whole plan of its time (``planned_*``: the seeds the
    file then gave each side), or a round of today's file."""
    a, b = frozenset(seeds_a), frozenset(seeds_b)
    if not a:
        return False
    if planned_a is not None and a >= frozenset(planned_a) and b >= frozenset(planned_b or ()):
        return True
    return any(a == ra and b == rb for ra, rb in rounds(spec, claim))


def is_interim(spec, claim: Claim, seeds_a, seeds_b) -> bool:
    """Whether a report on these seeds is on the way to a look the file plans: every seed of each side within the
    plan, some of them not finished yet (a side with none finished included), and not a look itself (a round's
    seeds all in). Its verdict waits."""
    a, b = frozenset(seeds_a), frozenset(seeds_b)
    if is_look(spec, claim, a, b):
        return False
    plan_a, plan_b = rounds(spec, claim)[-1]
    return a <= plan_a and b <= plan_b


def count_looks(spec, claim: Claim, seeds_a=(), seeds_b=(), history: pd.DataFrame | None = None) -> int:
    """``claim``'s looks: the file's plan, or the distinct sets of seeds the record and this report (on ``seeds_a``
    and ``seeds_b``) decided at a look, whichever is more."""
    decided = set()
    if history is not None and not history.empty:
        for _, row in history[history["claim"] == claim.name].iterrows():
            if str(row["look"]) == "True":
                decided.add(trials_of(claim, read_seeds(row["seeds_a"]), read_seeds(row["seeds_b"])))
    if is_look(spec, claim, seeds_a, seeds_b):
        decided.add(trials_of(claim, seeds_a, seeds_b))
    return max(planned_looks(spec, claim), len(decided))


def trials_of(claim: Claim, seeds_a, seeds_b) -> tuple[frozenset[int], frozenset[int]]:
    """What a look decided on: the seeds of each side that is a configuration (a baseline's or a constant's figures
    are not trials of the sweep: the same trials against them are the same look)."""
    return frozenset(seeds_a), frozenset(seeds_b) if isinstance(claim.b, dict) else frozenset()


def read_history(folder: Path | None) -> pd.DataFrame:
    """The record of the results ``folder`` (empty without one)."""
    path = None if folder is None else Path(folder) / HISTORY_FILE
    if path is None or not path.is_file():
        return pd.DataFrame(columns=list(COLUMNS))
    return pd.read_csv(path, dtype={"seeds_a": str, "seeds_b": str, "planned_a": str, "planned_b": str,
                                    "note": str}, keep_default_na=False, na_values={"p": [""], "p_adjusted": [""]})


def record(spec, outcomes, folder: Path, when: str | None = None) -> int:
    """Append to ``folder``'s record each claim of ``outcomes`` decided on seeds its last row does not hold; returns
    the rows added. A report published again on the same seeds adds nothing."""
    history = read_history(folder)
    when = when or datetime.date.today().isoformat()
    rows = []
    for o in outcomes:
        if not len(o.a):
            continue
        a, b = seeds_text(o.seeds_a), seeds_text(o.seeds_b)
        mine = history[history["claim"] == o.claim.name]
        if len(mine) and trials_of(o.claim, read_seeds(mine.iloc[-1]["seeds_a"]), read_seeds(
                mine.iloc[-1]["seeds_b"])) == trials_of(o.claim, o.seeds_a, o.seeds_b):
            continue
        planned_a, planned_b = rounds(spec, o.claim)[-1]
        rows.append({"published": when, "claim": o.claim.name, "seeds_a": a, "seeds_b": b,
                     "planned_a": seeds_text(planned_a), "planned_b": seeds_text(planned_b), "p": o.p,
                     "p_adjusted": o.p_adjusted, "level": o.level, "verdict": o.verdict.value,
                     "look": is_look(spec, o.claim, o.seeds_a, o.seeds_b, planned_a, planned_b), "note": ""})
    if rows:
        from train.sweep.results import write_csv

        write_csv(pd.concat([history, pd.DataFrame(rows, columns=list(COLUMNS))], ignore_index=True),
                  Path(folder) / HISTORY_FILE)
    return len(rows)
