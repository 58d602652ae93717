"""Claims about a follower beside the people population, declared in a file before its episodes are played, and
decided on the per-episode figures ``bench/beside_people.py measure`` keeps.

    python bench/people_claims.py docs/reproduction/shielded/claims.toml

The file (TOML) names the ``follower``, its ``baseline``, the ``leaders`` (``held_out``: every held-out person of
``populations/people.json``; ``astar``), the ``episodes`` a leader and the first ``seed``, the ``measure`` file
(relative to the claims file) and the ``measure_command`` that writes it, and its claims (``[[claim]]``: a ``name``, a
per-episode ``metric``, ``net`` or ``wrong`` pickups, and the ``direction`` it states, ``>`` or ``<``). The
measure file must be of those episodes, seeds and followers: a claim is decided on the data it was declared for.

Each claim is tested as a sweep's claim against a baseline is (``train.sweep.claims``): the paired t-test (scipy's
``ttest_rel``) of the follower's figure minus the baseline's over every episode beside the leaders, paired by leader
and episode seed (both played the same episodes); the file's claims are one family, Holm-adjusted; the verdict is
the sweep's one rule at 0.05 on the adjusted p, and the interval printed is the test's at 95%.

The episodes are the sample: a verdict is about these leaders, on episodes like these. Whether a difference holds
across leaders of other kinds is another question, with the leaders as the sample; the report prints each leader's
difference beside the verdicts, and the paired t-test across the leaders' means, for that reading (not a declared
test: six leaders decide little).
"""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from train.sweep.claim_spec import Direction  # noqa: E402
from train.sweep.claim_stats import Comparison, holm, t_test  # noqa: E402
from train.sweep.claims import ALPHA, verdict  # noqa: E402

METRICS = {"net": "net pickups", "wrong": "wrong pickups"}
LEADERS = ("held_out", "astar")
KEYS = ("description", "follower", "baseline", "leaders", "episodes", "seed", "measure", "measure_command", "claim")


class ClaimsError(ValueError):
    """A claims file or its measure file that cannot be decided: one line saying what is wrong and what is allowed."""


@dataclass(frozen=True)
class Decided:
    """A claim decided: both sides' means, the test (difference, its 95% interval, raw p), the family's Holm p the
    verdict reads, and the number of paired episodes."""

    name: str
    metric: str
    direction: Direction
    mean_a: float
    mean_b: float
    difference: float
    low: float
    high: float
    p: float
    p_adjusted: float
    verdict: str
    n: int


def read_claims(path: Path) -> dict:
    """The claims file, checked: every key known, the leaders, metrics and directions among those allowed."""
    try:
        spec = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as err:
        raise ClaimsError(f"{path}: cannot be read as TOML ({err})") from None
    unknown = sorted(set(spec) - set(KEYS))
    if unknown:
        raise ClaimsError(f"{path}: unknown key(s) {unknown}; allowed: {list(KEYS)}")
    missing = [k for k in KEYS if k not in spec and k != "description"]
    if missing:
        raise ClaimsError(f"{path}: missing {missing}")
    if spec["leaders"] not in LEADERS:
        raise ClaimsError(f"{path}: leaders={spec['leaders']!r}; allowed: {list(LEADERS)}")
    for claim in spec["claim"]:
        if claim.get("metric") not in METRICS or claim.get("direction") not in (">", "<") or not claim.get("name"):
            raise ClaimsError(f"{path}: claim {claim!r} needs a name, a metric in {list(METRICS)} and a direction "
                              f"'>' or '<'")
    return spec


def read_measure(spec: dict, path: Path) -> dict:
    """The measure file the claims name, refused unless it holds the declared episodes, seed and both followers."""
    measure = path.parent / spec["measure"]
    if not measure.is_file():
        raise ClaimsError(f"{measure} is missing: write it with {' '.join(spec['measure_command'].split())}")
    report = json.loads(measure.read_text())
    for key in ("episodes", "seed"):
        if report.get(key) != spec[key]:
            raise ClaimsError(f"{measure}: {key}={report.get(key)!r}, but the claims were declared for "
                              f"{key}={spec[key]!r}")
    absent = [f for f in (spec["follower"], spec["baseline"]) if f not in report.get("followers", [])]
    if absent:
        raise ClaimsError(f"{measure}: has no episodes of {absent} (it has {report.get('followers')})")
    if spec["leaders"] == "held_out":
        from colorgrid.policies.population import load_population

        expected = list(load_population("people#held_out"))
        if report.get("held_out") != expected:
            raise ClaimsError(f"{measure}: its held-out leaders are {report.get('held_out')}, but the population's "
                              f"are {expected}")
    return report


def episodes(report: dict, leaders: str, follower: str, metric: str) -> np.ndarray:
    """The follower's per-episode figure beside the leaders, leader by leader in the file's order."""
    names = report["held_out"] if leaders == "held_out" else ["astar"]
    return np.concatenate([np.asarray(report["cells"][n][follower][metric], dtype=float) for n in names])


def decide(spec: dict, report: dict) -> list[Decided]:
    """Every claim of ``spec`` on ``report``'s episodes, as one family."""
    tests = []
    for claim in spec["claim"]:
        a = episodes(report, spec["leaders"], spec["follower"], claim["metric"])
        b = episodes(report, spec["leaders"], spec["baseline"], claim["metric"])
        tests.append((claim, a, b, t_test(Comparison.PAIRED, a, b, 1 - ALPHA)))
    adjusted = holm([test.p for *_, test in tests])
    return [Decided(claim["name"], claim["metric"], Direction(claim["direction"]), float(a.mean()), float(b.mean()),
                    test.difference, test.low, test.high, test.p, p_adj,
                    verdict(Direction(claim["direction"]), test.difference, p_adj).value, len(a))
            for (claim, a, b, test), p_adj in zip(tests, adjusted)]


FORMS = {"net": "{:+.2f}", "wrong": "{:.2f}"}
"""How each metric's means print (a count of wrong pickups takes no sign; differences always do)."""


def table(decided: list[Decided]) -> str:
    """The claims as a markdown table: each side's mean, the difference with its interval, raw and Holm p, verdict."""
    rows = ["| claim | follower | baseline | follower - baseline [95% interval] | p | Holm p | episodes | verdict |",
            "|---|---:|---:|---|---:|---:|---:|---|"]
    for d in decided:
        form = FORMS[d.metric]
        rows.append(f"| {d.name} ({METRICS[d.metric]}, {d.direction.value}) | {form.format(d.mean_a)} | "
                    f"{form.format(d.mean_b)} | {d.difference:+.2f} [{d.low:+.2f}, {d.high:+.2f}] | {d.p:.3g} | "
                    f"{d.p_adjusted:.3g} | {d.n} | {d.verdict} |")
    return "\n".join(rows)


def by_leader(spec: dict, report: dict) -> str:
    """Each leader's mean difference (follower - baseline) on each claim's metric, and the paired t-test across the
    leaders' means: the reading with the leaders as the sample (not a declared test)."""
    from scipy import stats

    names = report["held_out"] if spec["leaders"] == "held_out" else ["astar"]
    metrics = list(dict.fromkeys(claim["metric"] for claim in spec["claim"]))
    rows = ["| leader | " + " | ".join(f"{METRICS[m]}: follower - baseline" for m in metrics) + " |",
            "|---|" + "---:|" * len(metrics)]
    means = {m: [] for m in metrics}
    for name in names:
        cells = []
        for m in metrics:
            difference = float(np.mean(np.asarray(report["cells"][name][spec["follower"]][m], dtype=float)
                                       - np.asarray(report["cells"][name][spec["baseline"]][m], dtype=float)))
            means[m].append(difference)
            cells.append(f"{difference:+.2f}")
        rows.append(f"| {name} | " + " | ".join(cells) + " |")
    if len(names) > 1:
        tests = [stats.ttest_1samp(means[m], 0.0) for m in metrics]
        rows.append(f"| across the {len(names)} leaders (t-test of their means, p) | "
                    + " | ".join(f"{np.mean(means[m]):+.2f} (p {t.pvalue:.2g})" for m, t in zip(metrics, tests)) + " |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("claims", type=Path, help="a claims file (TOML)")
    args = parser.parse_args(argv)
    try:
        spec = read_claims(args.claims)
        report = read_measure(spec, args.claims)
        decided = decide(spec, report)
    except ClaimsError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{spec['follower']} against {spec['baseline']} beside the {spec['leaders'].replace('_', '-')} leaders "
          f"({spec['episodes']} episodes each, seeds {spec['seed']}..{spec['seed'] + spec['episodes'] - 1}):\n")
    print(table(decided))
    every = all(d.verdict == "reproduced" for d in decided)
    print(f"\nevery claim reproduced: {'yes' if every else 'no'}")
    print("\nLeader by leader (the leaders as the sample; not a declared test):\n")
    print(by_leader(spec, report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
