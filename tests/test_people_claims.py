"""Claims about a follower beside the people population (``bench/people_claims.py``): decided on a constructed
measure file whose answers are known (scipy's paired t-test, Holm by hand), and refused on data they were not
declared for."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from colorgrid.policies.population import load_population  # noqa: E402
from people_claims import ClaimsError, decide, read_claims, read_measure  # noqa: E402

LEADERS = list(load_population("people#held_out"))


def write(tmp_path: Path, follower_net, baseline_net, follower_wrong, baseline_wrong, seed: int = 10) -> Path:
    n = len(follower_net) // len(LEADERS)
    cells = {leader: {"mine": {"net": follower_net[i * n:(i + 1) * n], "wrong": follower_wrong[i * n:(i + 1) * n]},
                      "base": {"net": baseline_net[i * n:(i + 1) * n], "wrong": baseline_wrong[i * n:(i + 1) * n]}}
             for i, leader in enumerate(LEADERS)}
    (tmp_path / "measure.json").write_text(json.dumps({"episodes": n, "seed": seed, "held_out": LEADERS,
                                                       "followers": ["base", "mine"], "cells": cells}))
    claims = tmp_path / "claims.toml"
    claims.write_text(f"""follower = "mine"
baseline = "base"
leaders = "held_out"
episodes = {n}
seed = 10
measure = "measure.json"
measure_command = "python bench/beside_people.py measure ..."
[[claim]]
name = "more net"
metric = "net"
direction = ">"
[[claim]]
name = "fewer wrong"
metric = "wrong"
direction = "<"
""")
    return claims


def test_each_claim_is_the_paired_test_over_episodes_held_to_holm(tmp_path):
    rng = np.random.default_rng(0)
    base_net, base_wrong = rng.normal(20, 4, 48), rng.poisson(2, 48).astype(float)
    mine_net, mine_wrong = base_net + rng.normal(0.9, 2, 48), base_wrong + rng.normal(-0.2, 1, 48)
    claims = write(tmp_path, mine_net.tolist(), base_net.tolist(), mine_wrong.tolist(), base_wrong.tolist())
    spec = read_claims(claims)
    net, wrong = decide(spec, read_measure(spec, claims))
    for got, a, b in ((net, mine_net, base_net), (wrong, mine_wrong, base_wrong)):
        expected = stats.ttest_rel(a, b)
        assert got.p == pytest.approx(expected.pvalue) and got.n == 48
        assert got.difference == pytest.approx(np.mean(a - b))
        low, high = expected.confidence_interval(0.95)
        assert (got.low, got.high) == (pytest.approx(low), pytest.approx(high))
    small, large = sorted([net.p, wrong.p])  # Holm by hand: the smaller p times 2, the larger times 1, kept ordered
    adjusted = {small: min(1, 2 * small), large: min(1, max(2 * small, large))}
    assert net.p_adjusted == pytest.approx(adjusted[net.p]) and wrong.p_adjusted == pytest.approx(adjusted[wrong.p])
    assert net.verdict == ("reproduced" if net.p_adjusted < 0.05 else "in direction only")


def test_the_opposite_direction_decided_is_not_reproduced(tmp_path):
    base = [20.0, 21, 19, 22, 20, 18, 21, 20, 19, 22, 20, 21]
    worse = [b - 3 + 0.1 * i for i, b in enumerate(base)]
    claims = write(tmp_path, worse, base, [1.0] * 12, [1.0, 2] * 6)
    spec = read_claims(claims)
    net, _ = decide(spec, read_measure(spec, claims))
    assert net.difference < 0 and net.verdict == "not reproduced"


def test_data_other_than_declared_is_refused_in_one_line(tmp_path):
    claims = write(tmp_path, [1.0] * 6, [1.0] * 6, [0.0] * 6, [0.0] * 6, seed=11)
    spec = read_claims(claims)
    with pytest.raises(ClaimsError, match=r"seed=11, but the claims were declared for seed=10"):
        read_measure(spec, claims)
    script = [sys.executable, str(ROOT / "bench" / "people_claims.py"), str(claims)]
    done = subprocess.run(script, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "declared for seed=10" in done.stderr
    (tmp_path / "measure.json").unlink()
    done = subprocess.run(script, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "is missing: write it with python bench/beside_people.py measure" in done.stderr


def test_episodes_beside_other_leaders_than_the_populations_are_refused(tmp_path):
    claims = write(tmp_path, [1.0] * 6, [1.0] * 6, [0.0] * 6, [0.0] * 6)
    measure = json.loads((tmp_path / "measure.json").read_text())
    measure["held_out"] = measure["held_out"][:-1]
    (tmp_path / "measure.json").write_text(json.dumps(measure))
    with pytest.raises(ClaimsError, match="its held-out leaders are"):
        read_measure(read_claims(claims), claims)


def test_a_claim_of_an_unknown_metric_is_refused(tmp_path):
    claims = write(tmp_path, [1.0] * 6, [1.0] * 6, [0.0] * 6, [0.0] * 6)
    claims.write_text(claims.read_text().replace('metric = "wrong"', 'metric = "speed"'))
    with pytest.raises(ClaimsError, match=r"a metric in \['net', 'wrong'\]"):
        read_claims(claims)


def test_the_shipped_claims_file_is_well_formed():
    spec = read_claims(ROOT / "docs" / "reproduction" / "shielded" / "claims.toml")
    assert spec["follower"].startswith("shielded:") and spec["baseline"] == "bayes-people"
    assert f"--episodes {spec['episodes']} --seed {spec['seed']}" in spec["measure_command"]
    assert spec["follower"] in spec["measure_command"] and spec["baseline"] in spec["measure_command"]


def test_the_docs_print_the_shielded_claims_as_decided_from_the_kept_episodes():
    """docs/ASSISTANT_RECIPE.md's table is the report's, row for row; the model card's and README's figures are its
    means, differences, intervals and Holm p at the precision they print."""
    script = [sys.executable, str(ROOT / "bench" / "people_claims.py"),
              str(ROOT / "docs" / "reproduction" / "shielded" / "claims.toml")]
    done = subprocess.run(script, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    claims, leaders = done.stdout.split("Leader by leader")
    rows = [line for line in claims.splitlines() if line.startswith("| ")]
    by_leader = [line for line in leaders.splitlines() if line.startswith("| ")]
    recipe = (ROOT / "docs" / "ASSISTANT_RECIPE.md").read_text()
    assert len(rows) == 3 and all(row in recipe.splitlines() for row in rows)  # the header and two claims
    assert len(by_leader) == 8 and all(row in recipe.splitlines() for row in by_leader)  # six leaders, and across
    assert "\nevery claim reproduced: yes\n" in done.stdout
    spec = read_claims(ROOT / "docs" / "reproduction" / "shielded" / "claims.toml")
    net, wrong = decide(spec, read_measure(spec, ROOT / "docs" / "reproduction" / "shielded" / "claims.toml"))
    card = (ROOT / "checkpoints" / "follower_shielded.md").read_text()
    for d, form in ((net, "{:+.2f}"), (wrong, "{:.2f}")):
        row = (f"| {form.format(d.mean_a)} | {form.format(d.mean_b)} | {d.difference:+.2f} [{d.low:+.2f}, "
               f"{d.high:+.2f}] | {d.p_adjusted:.3g} | {d.verdict} |")
        assert row in card, row
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert f"{net.mean_a:+.2f} against {net.mean_b:+.2f} net pickups" in readme
    assert f"{wrong.mean_a:.2f} against {wrong.mean_b:.2f} wrong" in readme
    assert f"Holm p {net.p_adjusted:.0e} and {wrong.p_adjusted:.0e}" in readme
