"""Assigning conditions to participants: arms, Latin squares, quotas.

An **arm** is what one participant gets: a condition (between subjects) or an order of every
condition (within subjects). ``arms(study)`` lists them; ``choose_arm`` picks one for a new
participant from the counts so far. Pure functions: the database keeps the counts.
"""

from __future__ import annotations

import random

from server.study.config import Study


def williams(n: int) -> list[list[int]]:
    """Williams' Latin square: every condition once per row and per position, and (for even ``n``) every
    ordered pair of neighbours exactly once; odd ``n`` needs the mirrored rows too (2n rows)."""
    if n == 1:
        return [[0]]
    first, low, high = [0], 1, n - 1
    while len(first) < n:
        first.append(low)
        low += 1
        if len(first) < n:
            first.append(high)
            high -= 1
    rows = [[(c + r) % n for c in first] for r in range(n)]
    return rows if n % 2 == 0 else rows + [row[::-1] for row in rows]


def arms(study: Study) -> list[list[int]]:
    """Each arm's trials as condition indices, in play order (``trials_per_condition`` repeats included)."""
    n, k = len(study.conditions), study.design.trials_per_condition
    if study.design.assignment == "between":
        return [[c] * k for c in range(n)]
    if study.design.order == "latin_square":
        orders = williams(n)
    else:  # fixed; "random" draws its order per participant (``trial_order``), over this one arm
        orders = [list(range(n))]
    return [order * k for order in orders]


def arm_labels(study: Study) -> list[str]:
    """Each arm's name: its condition (``C2``, between subjects) or its order (``C1 → C2 → C4 → C3``)."""
    if study.design.assignment == "between":
        return [f"C{arm[0] + 1}" for arm in arms(study)]
    return [" → ".join(f"C{c + 1}" for c in arm) for arm in arms(study)]


def choose_arm(counts: list[int], quota: int | None, balance: str, rng: random.Random) -> int | None:
    """The arm for the next participant, given how many each arm has; None when every arm is at its quota."""
    open_arms = [a for a, c in enumerate(counts) if quota is None or c < quota]
    if not open_arms:
        return None
    if balance == "balanced":
        fewest = min(counts[a] for a in open_arms)
        open_arms = [a for a in open_arms if counts[a] == fewest]
    return rng.choice(open_arms)


def trial_order(study: Study, arm: int, rng: random.Random) -> list[int]:
    """The condition of each trial for a participant in ``arm``."""
    order = arms(study)[arm]
    if study.design.assignment == "within" and study.design.order == "random":
        n = len(study.conditions)
        order = [c for _ in range(study.design.trials_per_condition) for c in rng.sample(range(n), n)]
    return order
