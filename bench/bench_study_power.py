"""The t-test power behind ``colorgrid study power``: ``server.study.power.t_test_power`` against the same integral
written with scipy's distributions.

``t_test_power`` integrates the noncentral t's tail over the spread's chi-square with the special functions that
``scipy.stats.chi2.ppf``, ``norm.sf`` and ``norm.cdf`` compute with (``gammaincinv``, ``ndtr``), without the
distributions' argument checks on every call. This script times both forms on a grid of cases (standardized
effects 0.05 to 50, 2 to 5,000 participants, alpha 0.05 and 0.01, paired and two groups: 252 cases) and counts the
cases whose two answers are the same float, bit for bit.

Prints, with the machine: the median seconds of each form for the whole grid over ``--repeats`` passes, with the
range, their ratio, and the identical cases.

Usage: python bench/bench_study_power.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import itertools
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

from scipy import integrate, stats  # noqa: E402

from server.study.power import t_test_power  # noqa: E402

EFFECTS = (0.05, 0.2, 0.5, 1.0, 2.0, 5.0, 50.0)
SIZES = (2, 3, 5, 10, 20, 50, 200, 1000, 5000)
ALPHAS = (0.05, 0.01)
CASES = list(itertools.product(EFFECTS, SIZES, ALPHAS, (True, False)))


def with_distributions(effect: float, n: int, alpha: float, paired: bool) -> float:
    """``t_test_power``'s integral written with scipy's distributions (its form before the special functions)."""
    df = n - 1 if paired else 2 * n - 2
    shift = effect * math.sqrt(n if paired else n / 2)
    critical = stats.t.ppf(1 - alpha / 2, df)

    def rejected(u: float) -> float:
        scale = critical * math.sqrt(stats.chi2.ppf(u, df) / df)
        return stats.norm.sf(scale - shift) + stats.norm.cdf(-scale - shift)

    return float(integrate.quad(rejected, 0.0, 1.0, limit=200)[0])


def grid_seconds(power, repeats: int) -> tuple[list[float], list[float]]:
    """Wall seconds of each of ``repeats`` passes over the grid, and the last pass's answers."""
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        answers = [power(*case) for case in CASES]
        seconds.append(time.perf_counter() - start)
    return seconds, answers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="passes over the grid for each form")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats {args.repeats} is invalid: at least 1")
    print(f"machine: {machine()}")
    special, new = grid_seconds(t_test_power, args.repeats)
    distributions, old = grid_seconds(with_distributions, args.repeats)
    same = sum(a == b or (math.isnan(a) and math.isnan(b)) for a, b in zip(new, old))
    for name, seconds in (("special functions (t_test_power)", special), ("scipy's distributions", distributions)):
        print(f"{name:<34} {statistics.median(seconds):8.3f} s  (range {min(seconds):.3f}-{max(seconds):.3f}, "
              f"{args.repeats} passes of {len(CASES)} cases)")
    print(f"ratio: {statistics.median(distributions) / statistics.median(special):.0f}x; "
          f"identical answers: {same} of {len(CASES)}")


if __name__ == "__main__":
    main()
