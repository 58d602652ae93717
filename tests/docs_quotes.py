"""What the docs print about the kept claims, read back and compared with the recomputed report at the precision
printed (tests/test_kept_verdicts.py). Two shapes are read:

* a claims table row (its first cell a claim's name): every column by its header (means and counts, the test,
  the difference with its interval and level, p, the p within and beyond a margin, Holm's p, the level and looks,
  power and seeds, declared, the verdict);
* a quote, ``VERDICT (figures)`` in any other table row or in README's and ASSISTANT_RECIPE's prose, whose claims
  ``QUOTES`` names in order. Its figures: ``+14.04 vs +21.97`` (the means), ``-7.93 [-20.41, +4.56]`` (with
  ``at 95%``), ``p 0.17`` or ``p < 1e-6``, ``Holm 0.17``, ``level 0.025``, ``within ±3: p 0.76``, ``beyond ±3: p
  0.24``, ``5 seeds`` (each side's count), ``at 3 seeds: -5.51, p 0.19`` (the first seeds alone, recomputed). A
  digit left over that none of these reads is a problem: every number a quote prints is checked.
"""

from __future__ import annotations

import math
import re

NUM = r"\d[\d.]*(?:e[+-]?\d+)?"
SIGNED = r"[+-]\d[\d.]*"
VERDICTS = ("not reproduced", "in direction only", "inconclusive", "exploratory", "interim", "reproduced")
QUOTE = re.compile(r"\*{0,2}\b(" + "|".join(VERDICTS) + r")\b\*{0,2} \(([^()]*)\)")


def agrees(printed: str, value: float, scale: float = 1.0) -> bool:
    """Whether ``printed`` is ``value`` (times ``scale``) at the precision printed: within half a unit of its last
    digit (``0.17``: 0.165 to 0.175; ``4e-10``: 3.5e-10 to 4.5e-10)."""
    value = value * scale
    if printed.strip() == "-":
        return not math.isfinite(value)
    mantissa, _, exponent = printed.strip().lstrip("+").partition("e")
    decimals = len(mantissa.partition(".")[2])
    unit = 10.0 ** (int(exponent or 0) - decimals)
    return math.isfinite(value) and abs(float(printed) - value) <= 0.5 * unit * (1 + 1e-9) + 1e-12


def _mean_n(cell: str, row: dict, side: str) -> list[str]:
    match = re.search(rf":\s*({SIGNED}|-)(?:\s*\((\d+)\))?$", cell)
    if match is None:
        return [f"side {side} {cell!r} is not 'NAME: MEAN (N)'"]
    out = [] if agrees(match.group(1), row[f"mean_{side}"]) else [f"mean {side} {match.group(1)}, "
                                                                   f"the report {row[f'mean_{side}']:+.4f}"]
    n = int(match.group(2)) if match.group(2) else 0
    return out + ([] if n == row[f"n_{side}"] else [f"n {side} {n}, the report {row[f'n_{side}']}"])


def _difference(cell: str, row: dict) -> list[str]:
    if cell == "-":  # a side with no finished trial yet
        return [] if not math.isfinite(row["difference"]) else ["a - b '-' where the report has a difference"]
    alone = re.fullmatch(rf"({SIGNED}) \(no interval at one seed\)", cell)  # a side of one seed: no spread
    if alone is not None:
        return _figures([("difference", alone.group(1))], row) + (
            [] if not math.isfinite(row["ci_low"]) else ["a - b printed without the interval the report gives"])
    match = re.fullmatch(rf"({SIGNED}) \[({SIGNED}), ({SIGNED})\] \(({NUM})%\)", cell)
    if match is None:
        return [f"a - b {cell!r} is not 'D [LOW, HIGH] (LEVEL%)' or 'D (no interval at one seed)'"]
    return _figures(zip(("difference", "ci_low", "ci_high"), match.groups()[:3]), row) + (
        [] if agrees(match.group(4), row["ci_level"], 100) else [f"interval at {match.group(4)}%, the report's "
                                                                  f"{100 * row['ci_level']:g}%"])


def _p(cell: str, row: dict) -> list[str]:
    first, *rest = cell.split("; ")
    out = _figures([("p", first)], row)
    for part in rest:
        match = re.fullmatch(rf"(within|beyond) ±({NUM}): ({NUM})", part)
        if match is None:
            return out + [f"p {part!r} is not 'within ±M: P' or 'beyond ±M: P'"]
        column = "p_equivalence" if match.group(1) == "within" else "p_outside"
        out += _figures([("margin", match.group(2)), (column, match.group(3))], row)
    return out


def _level(cell: str, row: dict) -> list[str]:
    match = re.fullmatch(rf"({NUM})(?: \((\d+) looks\))?", cell)
    if match is None:
        return [f"level {cell!r} is not 'LEVEL' or 'LEVEL (N looks)'"]
    looks = int(match.group(2) or 1)
    return _figures([("level", match.group(1))], row) + ([] if looks == row["looks"] else
                                                          [f"{looks} looks, the report {row['looks']}"])


def _power(cell: str, row: dict) -> list[str]:
    if cell == "-":
        decided, untested = row["verdict"] in ("reproduced", "not reproduced"), not math.isfinite(row["power"])
        return [] if decided or untested else ["power '-' for a claim not decided"]
    match = re.fullmatch(rf"({NUM}); (> 1000|\d+)", cell)
    if match is None:
        return [f"power {cell!r} is not 'POWER; SEEDS'"]
    seeds = math.inf if match.group(2) == "> 1000" else float(match.group(2))
    return _figures([("power", match.group(1))], row) + (
        [] if seeds == row["seeds_for_power"] else [f"{match.group(2)} seeds for 80%, the report "
                                                    f"{row['seeds_for_power']}"])


def _same(column: str):
    return lambda cell, row: [] if cell.strip("*") == str(row[column]) else [
        f"{column} {cell!r}, the report {row[column]!r}"]


COLUMNS = {"a": lambda c, r: _mean_n(c, r, "a"), "b": lambda c, r: _mean_n(c, r, "b"), "test": _same("test"),
           "a - b": _difference, "p": _p, "Holm p": lambda c, r: _figures([("p_adjusted", c)], r),
           "level": _level, "power": _power, "declared": _same("declared"), "verdict": _same("verdict")}
"""A claims table's columns, by the start of their header, and how each cell is checked."""


def claims_row(header: list[str], cells: list[str], row: dict) -> list[str]:
    """The problems of a claims table row against the report's ``row`` (a dict of ``claims.csv``'s columns)."""
    out = []
    for head, cell in zip(header[1:], cells[1:]):
        key = next((k for k in sorted(COLUMNS, key=len, reverse=True) if head.startswith(k)), None)
        if key is None:
            out.append(f"column {head!r} is not one the test reads")
        else:
            out += COLUMNS[key](cell, row)
    return out


def _figures(pairs, row: dict) -> list[str]:
    return [f"{column} {printed}, the report {row[column]:.6g}" for column, printed in pairs
            if not agrees(printed, row[column])]


PATTERNS = (  # the figures a quote may print, tried in this order; each match is removed from the text
    ("first", re.compile(rf"at (\d+) seeds: ({SIGNED}), p ({NUM})")),
    ("means", re.compile(rf"({SIGNED}) vs ({SIGNED})")),
    ("interval", re.compile(rf"({SIGNED}) \[({SIGNED}), ({SIGNED})\](?: at ({NUM})%)?")),
    ("within", re.compile(rf"within ±({NUM}): p ({NUM})")),
    ("beyond", re.compile(rf"beyond ±({NUM}): p ({NUM})")),
    ("holm", re.compile(rf"Holm ({NUM})")),
    ("level", re.compile(rf"level ({NUM})")),
    ("below", re.compile(rf"p < ({NUM})")),
    ("p", re.compile(rf"p ({NUM})")),
    ("seeds", re.compile(r"(\d+) seeds")),
)


def quote(verdict: str, figures: str, row: dict, first_seeds) -> list[str]:
    """The problems of a quote of the claim whose report is ``row``; ``first_seeds(k)`` recomputes its difference
    and p on each side's first ``k`` seeds."""
    out = [] if verdict == row["verdict"] else [f"verdict {verdict!r}, the report {row['verdict']!r}"]
    rest = figures
    for name, pattern in PATTERNS:
        for match in pattern.finditer(rest):
            g = match.groups()
            if name == "first":
                difference, p = first_seeds(int(g[0]))
                out += [f"at {g[0]} seeds {printed}, recomputed {value:.4g}" for printed, value in
                        ((g[1], difference), (g[2], p)) if not agrees(printed, value)]
            elif name == "means":
                out += _figures([("mean_a", g[0]), ("mean_b", g[1])], row)
            elif name == "interval":
                out += _figures(zip(("difference", "ci_low", "ci_high"), g[:3]), row)
                out += [] if g[3] is None or agrees(g[3], row["ci_level"], 100) else [f"interval at {g[3]}%"]
            elif name in ("within", "beyond"):
                column = "p_equivalence" if name == "within" else "p_outside"
                out += _figures([("margin", g[0]), (column, g[1])], row)
            elif name == "below":
                out += [] if row["p"] < float(g[0]) else [f"p < {g[0]}, the report {row['p']:.3g}"]
            elif name == "seeds":
                counts = {row["n_a"], row["n_b"]} - {0}
                out += [] if counts == {int(g[0])} else [f"{g[0]} seeds, the report {sorted(counts)}"]
            else:
                out += _figures([({"holm": "p_adjusted", "level": "level", "p": "p"}[name], g[0])], row)
        rest = pattern.sub(" ", rest)
    if re.search(r"\d", rest):
        out.append(f"a number the test does not read in ({figures})")
    return out
