"""A sweep file's claims as declared (``[[claim]]``): what each compares and the paper's direction, checked
against the file's parameters. ``train.sweep.claims`` decides them; docs/SWEEPS.md, "Claims and their verdicts"."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from train.sweep.checks import SweepError, bad, same_value


@dataclass(frozen=True)
class Baseline:
    """A claim's side b that is a baseline's per-seed figures (``b = { baseline = "astar/copy" }``): the policy
    ``policy`` beside the partner ``partner``, evaluated on each trial seed's own evaluation seeds and kept in the
    results folder (``train.sweep.baselines``). The claim is tested paired by seed."""

    name: str
    """``<partner>/<policy>`` as the kept file names it (``astar/copy``, ``population_people_held_out/bayes``)."""

    def __post_init__(self):
        partner, _, policy = self.name.partition("/")
        if not partner or not policy:
            raise SweepError(f"baseline={self.name!r} is invalid: '<partner>/<policy>', e.g. 'astar/copy'")

    @property
    def policy(self) -> str:
        return self.name.partition("/")[2]

    @property
    def partner(self) -> str:
        return self.name.partition("/")[0]


class Direction(str, Enum):
    GREATER = ">"
    LESS = "<"
    SAME = "~"


@dataclass(frozen=True)
class Claim:
    """One claim of a sweep file (``[[claim]]``)."""

    name: str
    """A short name, e.g. ``annealing helps``."""
    a: dict
    """Side a: ``{parameter: value or [values]}`` (a parameter left out pools over all its values)."""
    b: dict | float | Baseline
    """Side b: a configuration as ``a``, a baseline's per-seed figures, or a constant (a true threshold: 0)."""
    direction: Direction
    margin: float = 0.0
    """``~`` only: the largest difference that counts as none, in the column's units (> 0)."""
    metric: str = ""
    """The final column compared (the sweep's metric when empty)."""
    paper: str = ""
    """The paper's words (or figures) for the claim."""
    b_name: str = ""
    """What a constant or baseline side b is (``the copy follower beside the same leader``)."""

    def side_name(self, side: dict | float | Baseline, name: str = "") -> str:
        if isinstance(side, Baseline):
            return name or f"{side.policy} beside {side.partner}"
        if not isinstance(side, dict):
            return name or f"{side:+g}"
        if not side:
            return "every configuration"
        return ", ".join(f"{k}={'|'.join(map(str, v)) if isinstance(v, list) else v}" for k, v in side.items())


def parse_claims(params: tuple, metric: str, summarised: set[str], tables: tuple) -> tuple[Claim, ...]:
    """The ``[[claim]]`` tables of a sweep file (``train.sweep.file.ClaimTable``s, each already checked on its own),
    checked against its parameters (``Param``s), its ``metric`` and the columns its trials table ``summarised``."""
    claims, names = [], set()
    for i, table in enumerate(tables):
        where = f"claim[{i}]"
        if table.name in names:
            raise bad(f"{where}.name", table.name, "a non-empty name no other claim has")
        names.add(table.name)
        column = table.metric if table.metric is not None else metric
        if column != metric and column not in summarised:
            raise bad(f"{where}.metric", column, f"the sweep's metric or a column the trials table summarises: "
                                                 f"{sorted(summarised)}")
        a = _side(params, f"{where}.a", table.a, constant_ok=False)
        b = _side(params, f"{where}.b", table.b, constant_ok=True)
        if isinstance(b, dict) and _overlap(params, a, b):
            raise bad(f"{where}.b", table.b, "a side sharing no configuration with a")
        if isinstance(b, Baseline) and not _one_configuration(params, a):
            raise bad(f"{where}.a", table.a, "one configuration (one value of each listed parameter): a side "
                                             "against a baseline is paired with it by seed")
        claims.append(Claim(table.name, a, b, Direction(table.expect), float(table.margin or 0.0), column,
                            table.paper, table.b_name))
    return tuple(claims)


def _one_configuration(params: tuple, side: dict) -> bool:
    return all(p.name in side and not isinstance(side[p.name], list) for p in params if not p.random)


def _side(params: tuple, where: str, value, constant_ok: bool) -> dict | float | Baseline:
    if constant_ok and isinstance(value, dict) and "baseline" in value:
        if set(value) != {"baseline"} or not isinstance(value["baseline"], str):
            raise bad(where, value, "{ baseline = '<partner>/<policy>' } alone, e.g. { baseline = 'astar/copy' }")
        try:
            return Baseline(value["baseline"])
        except SweepError as error:
            raise SweepError(f"{where}.{error}") from None
    if constant_ok and isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise bad(where, value, "a finite number")
        return float(value)
    if not isinstance(value, dict):
        allowed = "a table {parameter = value or [values]}" + (
            ", { baseline = '<partner>/<policy>' } or a number (a threshold)" if constant_ok else "")
        raise bad(where, value, allowed)
    side = {}
    for name, wanted in value.items():
        param = next((p for p in params if p.name == name and not p.random), None)
        if param is None:
            raise bad(where, name, f"one of the listed parameters {[p.name for p in params if not p.random]}")
        if isinstance(wanted, list) and not wanted:
            raise bad(f"{where}.{name}", wanted, f"a value or a non-empty list of values, of {list(param.values)}")
        chosen = []
        for v in wanted if isinstance(wanted, list) else [wanted]:
            listed = [p for p in param.values if same_value(p, v)]
            if not listed:
                raise bad(f"{where}.{name}", v, f"one of {list(param.values)}")
            chosen.append(listed[0])
        side[name] = chosen if isinstance(wanted, list) else chosen[0]
    return side


def parse_selection(params: tuple, where: str, value) -> dict:
    """A table ``{parameter = value or [values]}`` naming configurations (a claim's side, a ``[[more_seeds]]``
    table's ``where``), each value as the parameter lists it."""
    return _side(params, where, value, constant_ok=False)


def _overlap(params: tuple, a: dict, b: dict) -> bool:
    """Whether some configuration would be on both sides."""
    for param in params:
        if param.random:
            continue
        in_a = [v for v in param.values if matches_value(a.get(param.name, param.values), v)]
        in_b = [v for v in param.values if matches_value(b.get(param.name, param.values), v)]
        if not any(same_value(x, y) for x in in_a for y in in_b):
            return False
    return True


def matches_value(wanted, value) -> bool:
    options = wanted if isinstance(wanted, (list, tuple)) else [wanted]
    return any(same_value(w, value) for w in options)


def matches(where: dict, values) -> bool:
    """Whether the configuration with parameter ``values`` (a mapping by name) is one that ``where`` names (a
    claim's side, a ``[[more_seeds]]`` table's ``where``): each named parameter has one of the named values."""
    return all(matches_value(wanted, values.get(name)) for name, wanted in where.items())
