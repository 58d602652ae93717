"""The statistics of a claim's verdict and of the measures beside it, each against a known answer: the paired test
against scipy's ``ttest_rel``, the interval at the claim's level against scipy's own, Holm's adjustment against a
hand count, the seeds for 80% power against Cohen's table, the interquartile mean, the stratified bootstrap, the
probability of improvement and the single-agent rule by hand; the looks counted from the record; a claim against a
baseline read from a kept baselines.json and paired by seed."""

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from tests.test_sweep_claims import BASE, claim, fake_trial, sweep_folder, trials_table
from train.sweep import claim_stats as st
from train.sweep.claim_stats import Comparison
from train.sweep.claim_table import format_claims
from train.sweep.claim_table import table as claims_table
from train.sweep.claims import Verdict, evaluate
from train.sweep.looks import HISTORY_FILE, count_looks, read_history
from train.sweep.report import publish_report
from train.sweep.spec import SweepError, load_sweep

A = '{ rewards = "+4/-1", aux = 0.0 }'
B = '{ rewards = "+1/-1", aux = 0.0 }'


def test_the_paired_test_is_scipys_ttest_rel_with_its_interval_at_the_claims_level():
    a, b = [22.5, 22.6, 22.5, 22.4, 21.4], [19.8, 19.8, 21.8, 21.2, 19.2]
    test = st.t_test(Comparison.PAIRED, a, b, 0.975)
    expected = stats.ttest_rel(a, b)
    interval = expected.confidence_interval(0.975)
    assert test.p == pytest.approx(expected.pvalue) and test.difference == pytest.approx(np.mean(a) - np.mean(b))
    assert (test.low, test.high) == pytest.approx((interval.low, interval.high))
    wider, narrower = st.t_test(Comparison.PAIRED, a, b, 0.975), st.t_test(Comparison.PAIRED, a, b, 0.95)
    assert wider.low < narrower.low and wider.high > narrower.high  # the claim's level, not 95%
    # a pairing the seeds share: the paired p is far smaller than Welch's on the same numbers
    shared = [10.0, 20.0, 30.0]
    paired = st.t_test(Comparison.PAIRED, [s + 1 for s in shared], [s + 0.1 * i for i, s in enumerate(shared)], 0.95)
    welch = st.t_test(Comparison.WELCH, [s + 1 for s in shared], [s + 0.1 * i for i, s in enumerate(shared)], 0.95)
    assert paired.p < 0.05 < welch.p


def test_one_sample_interval_is_of_the_difference_at_the_given_level():
    test = st.t_test(Comparison.ONE_SAMPLE, [20.0, 21.0, 22.0], 19.72, 0.975)
    half = stats.t.ppf(1 - 0.025 / 2, 2) / math.sqrt(3)
    assert (test.low, test.high) == pytest.approx((1.28 - half, 1.28 + half))


def test_holm_against_a_hand_count():
    # sorted: 0.005 x 4 = 0.02; 0.01 x 3 = 0.03; 0.03 x 2 = 0.06; 0.04 x 1 = 0.04, raised to 0.06 (step-down);
    # a claim without a p is not in the family
    adjusted = st.holm([0.01, 0.04, math.nan, 0.03, 0.005])
    assert adjusted[:2] == pytest.approx([0.03, 0.06]) and math.isnan(adjusted[2])
    assert adjusted[3:] == pytest.approx([0.06, 0.02])
    assert st.holm([0.6, 0.9]) == pytest.approx([1.0, 1.0])


@pytest.mark.parametrize("d, seeds", [(0.5, 64), (0.8, 26), (1.0, 17)])
def test_seeds_for_power_match_cohens_table(d, seeds):
    """Cohen (1988), Table 2.4.1: n per group for power 0.80, two-sided alpha 0.05, two independent samples (its d = 0.2, 393, is a normal approximation; the t-test needs 394)."""
    b = np.array([-1.0, 0.0, 1.0])  # sd 1 in both sides: Cohen's d is the difference
    power = st.power(Comparison.WELCH, b + d, b, d, 0.05)
    assert power.seeds == seeds and 0 < power.now < 0.8
    # the smallest difference 3 seeds a side detect: the one the test has 80% power at
    at = st.power(Comparison.WELCH, b + power.detectable, b, power.detectable, 0.05)
    assert at.now == pytest.approx(0.8, abs=1e-3) and at.seeds == 3


def test_seeds_for_power_of_a_paired_test():
    """A paired test is a one-sample test of the differences: d = 0.5 at two-sided 0.05 needs 34 pairs for power
    0.80 (G*Power's one-sample t-test; n = 33.4), d = 0.8 needs 15."""
    differences = np.array([-1.0, 0.0, 1.0])
    assert st.power(Comparison.ONE_SAMPLE, differences + 0.5, 0.0, 0.5, 0.05).seeds == 34
    assert st.power(Comparison.PAIRED, differences + 0.8, np.zeros(3), 0.8, 0.05).seeds == 15


def test_a_difference_too_small_to_chase_and_no_difference():
    b = np.array([-1.0, 0.0, 1.0])
    assert math.isinf(st.power(Comparison.WELCH, b + 0.01, b, 0.01, 0.05).seeds)
    assert math.isnan(st.power(Comparison.WELCH, [1.0], b, 1.0, 0.05).seeds)  # one seed: no spread to read


def test_interquartile_mean_and_the_stratified_bootstrap():
    assert st.iqm([8, 1, 7, 2, 6, 3, 5, 4]) == pytest.approx(4.5)  # the middle half: 3, 4, 5, 6
    # each configuration's seeds are resampled within it: two strata without spread give one IQM every time
    estimate, low, high = st.iqm_interval([[0.0, 0.0, 0.0], [10.0, 10.0, 10.0]])
    assert (estimate, low, high) == pytest.approx((5.0, 5.0, 5.0))
    estimate, low, high = st.iqm_interval([[1.0, 2.0, 3.0, 4.0, 5.0]])
    assert estimate == pytest.approx(3.0) and 1.0 <= low < 3.0 < high <= 5.0
    assert st.iqm_interval([[1.0, 2.0, 3.0, 4.0, 5.0]]) == (estimate, low, high)  # a fixed seed: the same digits
    assert math.isnan(st.iqm_interval([[4.0]])[1])


def test_probability_of_improvement_and_single_agent_solutions():
    # pairs with a above b: 1>0, 2>0, 3>0, 3>2 (4 of 9), and 2 = 2 a tie (a half)
    assert st.probability_of_improvement([1, 2, 3], [0, 2, 4]) == pytest.approx(4.5 / 9)
    assert st.probability_of_improvement([1.0, 2.0, 3.0], 2.0) == pytest.approx(0.5)
    assert [st.single_agent(*team) for team in [(10, 4), (10, 6), (-0.5, 3), (-0.5, -0.4), (4, 10)]] == \
        [True, False, True, False, True]


def test_every_claim_of_a_file_is_one_family(tmp_path):
    path = tmp_path / "claims.toml"
    path.write_text(BASE + claim("strong", A, B, ">") + claim("weak", '{ rewards = "+2/-1", aux = 0.0 }', B, ">")
                    + claim("weak too", '{ rewards = "+2/-1", aux = 0.2 }', '{ rewards = "+1/-1", aux = 0.2 }', ">"))
    spec = load_sweep(path)
    a, b = [1.0, 3.0, 5.0, 7.0, 9.0], [0.0, 1.0, 2.0]  # Welch's p 0.046
    table = trials_table({("+4/-1", 0.0): [10.0, 11.0, 12.0], ("+1/-1", 0.0): b, ("+2/-1", 0.0): a,
                          ("+2/-1", 0.2): a, ("+1/-1", 0.2): b})
    strong, weak, weak_too = evaluate(spec, table)
    assert [o.p_adjusted for o in (strong, weak, weak_too)] == pytest.approx(st.holm([strong.p, weak.p, weak_too.p]))
    # Holm by hand: the two 0.046 are the 2nd and 3rd smallest of 3: 0.046 x 2, and the last raised to it
    assert weak.p_adjusted == pytest.approx(2 * weak.p) == pytest.approx(weak_too.p_adjusted)
    assert weak.p < 0.05 <= weak.p_adjusted and weak.verdict is Verdict.IN_DIRECTION
    assert strong.verdict is Verdict.REPRODUCED


def baselines_file(results: Path, per_seed: list[float]) -> None:
    results.mkdir(parents=True, exist_ok=True)
    (results / "baselines.json").write_text(json.dumps({
        "seeds": [1_000_000 + s for s in range(len(per_seed))],
        "baselines": {"astar/copy": {"net_pickups_per_seed": per_seed}}}))


def test_a_claim_against_a_baseline_is_paired_by_seed(tmp_path):
    results = tmp_path / "kept"
    baselines_file(results, [1.0, 2.0, 3.5, 100.0])  # seed 3 has no trial: left out of the pairs
    path = tmp_path / "claims.toml"
    beside_astar = BASE.replace('"env.asymmetric=true"]', '"env.asymmetric=true", "leader.policy=astar", "eval_every=1"]')
    path.write_text(f'results = "{results}"\n' + beside_astar + claim(  # the main evaluation plays beside A*
        "beats copy", A, '{ baseline = "astar/copy" }', ">", 'metric = "eval/follower_net_pickups"\nb_name = "copy"'))
    spec = load_sweep(path)
    trials = trials_table({("+4/-1", 0.0): [-2.0, -3.0, -4.0]})  # follower_net_pickups: 2, 3, 4
    [o] = evaluate(spec, trials.rename(columns={"final_follower_net_pickups": "final_eval/follower_net_pickups"}))
    expected = stats.ttest_rel([2.0, 3.0, 4.0], [1.0, 2.0, 3.5])
    assert o.kind is Comparison.PAIRED and o.b == [1.0, 2.0, 3.5] and o.seeds_b == (0, 1, 2)
    assert o.p == pytest.approx(expected.pvalue) and o.difference == pytest.approx(2.5 / 3)
    assert claims_table([o]).loc[0, "test"] == "paired" and "| paired |" in format_claims([o])


@pytest.mark.parametrize("b, expected", [
    ('{ baseline = "copy" }', "claim[0].b.baseline='copy' is invalid: '<partner>/<policy>'"),
    ('{ baseline = "astar/copy", seeds = 3 }', "is invalid: { baseline = '<partner>/<policy>' } alone"),
])
def test_a_bad_baseline_side_is_one_line(tmp_path, b, expected):
    path = tmp_path / "claims.toml"
    path.write_text(BASE + claim("c", A, b, ">"))
    with pytest.raises(SweepError) as caught:
        load_sweep(path)
    assert expected in str(caught.value) and "\n" not in str(caught.value)
    path.write_text(BASE + claim("c", '{ rewards = "+4/-1" }', '{ baseline = "astar/copy" }', ">"))
    with pytest.raises(SweepError, match="claim\\[0\\].a=.* one configuration"):
        load_sweep(path)


def test_looks_are_counted_from_the_plan_and_the_record(tmp_path):
    path = tmp_path / "claims.toml"
    path.write_text(BASE + claim("c", A, B, ">"))
    spec = load_sweep(path)
    [c] = spec.claims
    assert count_looks(spec, c, (0, 1, 2), (0, 1, 2)) == 1
    record = pd.DataFrame([
        {"claim": "c", "seeds_a": "0 1", "seeds_b": "0 1", "look": False},  # progress toward the plan: no look
        {"claim": "c", "seeds_a": "0 1 2", "seeds_b": "0 1 2", "look": True},
        {"claim": "c", "seeds_a": "0 1 2 3", "seeds_b": "0 1 2 3", "look": True},  # seeds beyond the plan, decided
    ])
    assert count_looks(spec, c, (0, 1, 2), (0, 1, 2), record) == 2
    assert count_looks(spec, c, (0, 1, 2), (0, 1, 2), record.iloc[:2]) == 1


def test_publishing_appends_to_the_record_once_per_set_of_seeds(tmp_path):
    results = tmp_path / "kept"
    folder = sweep_folder(tmp_path, claim("c", A, B, ">"), results)
    for seed in range(2):
        fake_trial(folder, f"trial_a{seed}", "+4/-1", 0.0, seed, [9.0 + seed, 11.0 + seed])
        fake_trial(folder, f"trial_b{seed}", "+1/-1", 0.0, seed, [1.0 + seed, 1.0 + seed])
    publish_report(folder)
    publish_report(folder)
    history = read_history(results)
    assert list(history["seeds_a"]) == ["0 1"] and not history.loc[0, "look"]  # 2 of the 3 seeds planned
    for seed in (2,):
        fake_trial(folder, f"trial_a{seed}", "+4/-1", 0.0, seed, [9.0 + seed, 11.0 + seed])
        fake_trial(folder, f"trial_b{seed}", "+1/-1", 0.0, seed, [1.0 + seed, 1.0 + seed])
    _, _, text = publish_report(folder)
    history = pd.read_csv(results / HISTORY_FILE)
    assert list(history["seeds_a"].astype(str)) == ["0 1", "0 1 2"] and list(history["look"]) == [False, True]
    assert "Holm" in text
