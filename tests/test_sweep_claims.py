"""A sweep's claims: each verdict of the one rule on constructed tables with known answers (Welch's interval and
p checked against the closed forms), pooled sides, baselines, unfinished trials left out, the sweep file's
mistakes in one line each, and the report and kept results built from real sweep folders. No Ray is started
here (tests/test_sweep.py runs sweeps that keep and skip trials)."""

import json
import math
from pathlib import Path

import pandas as pd
import pytest

from colorgrid_apps.cli import main
from train.sweep.claim_table import format_claims
from train.sweep.claim_table import table as claims_table
from train.sweep.claims import Verdict, evaluate, level
from train.sweep.report import publish_report, write_report
from train.sweep.results import committed_keys
from train.sweep.spec import SweepError, load_sweep

BASE = """
description = "claims"
preset = "default"
set = ["total_steps=4096", "env.asymmetric=true"]
seeds = [0, 1, 2]
metric = "team_reward"
final_window = 2

[params.rewards.options]
"+4/-1" = { "env.goal_reward" = 4.0 }
"+2/-1" = { "env.goal_reward" = 2.0 }
"+1/-1" = { "env.goal_reward" = 1.0 }

[params.aux]
keys = ["follower.aux_coef"]
grid = [0.0, 0.2]
"""


def spec_with(tmp_path: Path, claims: str, top: str = ""):
    path = tmp_path / "claims.toml"
    path.write_text(top + BASE + claims)
    return load_sweep(path)


def trials_table(values: dict, finished: bool = True) -> pd.DataFrame:
    """A trials table: ``{(rewards, aux): [final per seed]}``."""
    rows = []
    for (rewards, aux), finals in values.items():
        for seed, final in enumerate(finals):
            rows.append({"trial": f"t_{rewards}_{aux}_{seed}", "configuration": f"rewards={rewards}, aux={aux}",
                         "rewards": rewards, "aux": aux, "seed": seed, "finished": finished,
                         "final_team_reward": final, "final_follower_net_pickups": -final})
    return pd.DataFrame(rows)


def claim(name: str, a: str, b: str, expect: str, extra: str = "") -> str:
    return f'\n[[claim]]\nname = "{name}"\na = {a}\nb = {b}\nexpect = "{expect}"\n{extra}\n'


A = '{ rewards = "+4/-1", aux = 0.0 }'
B = '{ rewards = "+1/-1", aux = 0.0 }'


def decided(tmp_path, expect: str, a_values, b_values, extra: str = ""):
    spec = spec_with(tmp_path, claim("c", A, B, expect, extra))
    table = trials_table({("+4/-1", 0.0): a_values, ("+1/-1", 0.0): b_values})
    [outcome] = evaluate(spec, table)
    return outcome


def test_welch_interval_and_p_match_the_closed_form(tmp_path):
    o = decided(tmp_path, ">", [10.0, 11.0, 12.0], [0.0, 1.0, 2.0])
    # equal variances (1) and sizes (3): se = sqrt(1/3 + 1/3), Welch's df = 4, t = 10 / se
    se = math.sqrt(2 / 3)
    assert o.difference == pytest.approx(10.0)
    assert (o.low, o.high) == pytest.approx((10 - 2.7764451 * se, 10 + 2.7764451 * se), abs=1e-5)
    t, u = 10 / se, 1 + (10 / se) ** 2 / 4  # Student's t with 4 degrees of freedom, two-sided, in closed form
    assert o.p == pytest.approx(1 - 0.75 * (t / math.sqrt(u)) * (1 - t * t / (12 * u)), rel=1e-6)
    assert o.p < 0.001 and o.verdict is Verdict.REPRODUCED


def test_one_sample_against_a_baseline_matches_the_closed_form(tmp_path):
    spec = spec_with(tmp_path, claim("beats copy", A, "19.72", ">", 'b_name = "copy follower"'))
    [o] = evaluate(spec, trials_table({("+4/-1", 0.0): [20.0, 21.0, 22.0]}))
    t = (21 - 19.72) / (1 / math.sqrt(3))
    assert o.p == pytest.approx(1 - t / math.sqrt(2 + t * t), rel=1e-6)  # two-sided p for 2 degrees of freedom
    assert o.difference == pytest.approx(1.28) and o.verdict is Verdict.IN_DIRECTION
    assert (o.low, o.high) == pytest.approx((1.28 - 4.3026527 / math.sqrt(3), 1.28 + 4.3026527 / math.sqrt(3)))


@pytest.mark.parametrize("expect, a, b, verdict", [
    (">", [10, 11, 12], [0, 1, 2], Verdict.REPRODUCED),
    (">", [2, 3, 4], [0, 2, 4], Verdict.IN_DIRECTION),
    (">", [0, 1, 2], [10, 11, 12], Verdict.NOT_REPRODUCED),
    (">", [0, 2, 4], [2, 3, 4], Verdict.INCONCLUSIVE),
    ("<", [0, 1, 2], [10, 11, 12], Verdict.REPRODUCED),
    ("<", [0, 2, 4], [2, 3, 4], Verdict.IN_DIRECTION),
    ("<", [10, 11, 12], [0, 1, 2], Verdict.NOT_REPRODUCED),
    ("<", [2, 3, 4], [0, 2, 4], Verdict.INCONCLUSIVE),
])
def test_directional_verdicts(tmp_path, expect, a, b, verdict):
    assert decided(tmp_path, expect, [float(v) for v in a], [float(v) for v in b]).verdict is verdict


@pytest.mark.parametrize("a, b, margin, verdict", [
    ([5.0, 5.1, 4.9, 5.05, 4.95], [5.02, 4.98, 5.0, 5.1, 4.9], 2.0, Verdict.REPRODUCED),  # shown within the margin
    ([0.0, 5.0, 10.0], [1.0, 6.0, 9.0], 2.0, Verdict.IN_DIRECTION),  # means within it, too spread to show it
    ([10.0, 10.5, 11.0], [0.0, 0.5, 1.0], 1.0, Verdict.NOT_REPRODUCED),  # a difference beyond it, shown
    ([0.0, 10.0, 20.0], [-5.0, 0.0, 5.0], 1.0, Verdict.INCONCLUSIVE),  # beyond it, not shown
])
def test_no_difference_verdicts_need_the_equivalence_test(tmp_path, a, b, margin, verdict):
    o = decided(tmp_path, "~", a, b, f"margin = {margin}")
    assert o.verdict is verdict
    if verdict is Verdict.REPRODUCED:
        assert o.p_equivalence < 0.05 < o.p  # no difference found, and equivalence shown
    if verdict is Verdict.IN_DIRECTION:
        assert o.p_equivalence >= 0.05 and abs(o.difference) <= margin


def test_a_claim_tested_again_on_added_seeds_is_held_to_alpha_over_its_looks(tmp_path):
    """Seeds a ``[[more_seeds]]`` table adds to a claim's side make a second test of the claim: its verdict is at
    0.05 / 2 (Bonferroni), and the report and claims.csv say so; a claim whose sides got no seeds keeps 0.05."""
    a, b = [1.0, 3.0, 5.0, 7.0, 9.0], [0.0, 1.0, 2.0]  # Welch's p = 0.046: between 0.025 and 0.05
    once = decided(tmp_path, ">", a, b)
    assert once.looks == 1 and 0.025 < once.p < 0.05 and once.verdict is Verdict.REPRODUCED
    more = '\n[[more_seeds]]\nseeds = [3, 4]\nwhere = { rewards = "+4/-1", aux = 0.0 }\n'
    spec = spec_with(tmp_path, claim("again", A, B, ">") + claim("untouched", '{ rewards = "+2/-1", aux = 0.0 }',
                                                                  B, ">") + more)
    table = trials_table({("+4/-1", 0.0): a, ("+1/-1", 0.0): b, ("+2/-1", 0.0): [10.0, 11.0, 12.0]})
    again, untouched = evaluate(spec, table)
    assert (again.looks, again.p) == (2, pytest.approx(once.p)) and again.verdict is Verdict.IN_DIRECTION
    assert untouched.looks == 1
    assert f"| {again.p:.3g} | {again.p_adjusted:.3g} | 0.025 (2 looks) |" in format_claims([again, untouched])
    rows = claims_table([again, untouched])
    assert list(rows["looks"]) == [2, 1] and list(rows["level"]) == [0.025, 0.05]
    assert list(rows["verdict"]) == ["in direction only", "reproduced"]
    # other seeds through its other side are a third look; the same seeds through it are the same round; seeds
    # reaching neither side are none
    third = more + '\n[[more_seeds]]\nseeds = [5]\nwhere = { rewards = ["+1/-1"] }\n'
    third += '\n[[more_seeds]]\nseeds = [4, 3]\nwhere = { rewards = "+1/-1" }\n'
    third += '\n[[more_seeds]]\nseeds = [6]\nwhere = { aux = 0.2 }\n'
    spec = spec_with(tmp_path, claim("again", A, B, ">") + third)
    assert [o.looks for o in evaluate(spec, table)] == [3]
    unfinished = evaluate(spec, trials_table({("+4/-1", 0.0): a}))  # side b has no finished trial: no p, no level
    assert "(3 looks)" in format_claims(unfinished) and unfinished[0].verdict is Verdict.INTERIM  # b's to come
    assert level(3) == pytest.approx(0.05 / 3)


def test_seeds_short_of_the_plan_are_interim_and_no_spread_is_inconclusive(tmp_path):
    """A report on fewer seeds than the file plans (seeds 0-2) is on the way to its look: the verdict waits, however
    the figures read; the plan's seeds all in with no spread between them is inconclusive."""
    o = decided(tmp_path, ">", [10.0], [0.0, 1.0, 2.0])
    assert o.verdict is Verdict.INTERIM and math.isnan(o.p) and o.difference == pytest.approx(9.0)
    early = decided(tmp_path, ">", [10.0, 11.0], [0.0, 1.0])  # p 0.01: reproduced, were it the planned look
    assert early.p < 0.05 and early.verdict is Verdict.INTERIM and "**interim**" in format_claims([early])
    assert decided(tmp_path, ">", [10.0, 11.0, 12.0], [0.0, 1.0, 2.0]).verdict is Verdict.REPRODUCED
    assert decided(tmp_path, ">", [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]).verdict is Verdict.INCONCLUSIVE


def test_a_side_with_no_finished_trial_reads_as_such_in_the_report(tmp_path):
    """A sweep still running: an arm with no trial finished yet is short of the plan like one with some (interim,
    whichever side it is), and the report prints no number for it."""
    o = decided(tmp_path, ">", [], [0.0, 1.0, 2.0])
    shown = format_claims([o])
    assert o.verdict is Verdict.INTERIM and "nan" not in shown
    assert "(n=0)" in shown and "| - |" in shown and "a: none finished; b: +0.00, +1.00, +2.00" in shown
    assert decided(tmp_path, ">", [0.0, 1.0, 2.0], []).verdict is Verdict.INTERIM
    assert decided(tmp_path, ">", [], []).verdict is Verdict.INTERIM
    threshold = spec_with(tmp_path, claim("above zero", A, "0.0", ">"))
    assert [o.verdict for o in evaluate(threshold, trials_table({}))] == [Verdict.INTERIM]


def test_a_baseline_not_computed_yet_leaves_a_finished_claim_undecided_not_interim(tmp_path):
    """Interim counts the trials run, not the baseline's figures: with every planned trial finished and no
    ``baselines.json`` kept, the claim has nothing to pair with and is inconclusive; with a trial still to run it
    is interim."""
    metric = "eval_astar/follower_net_pickups"
    path = tmp_path / "claims.toml"
    evaluated = 'set = ["eval_every=1", "leader.policy=astar", "eval_partners=[\\"astar\\"]", '
    path.write_text(BASE.replace("set = [", evaluated)
                    + claim("beats copy", A, '{ baseline = "astar/copy" }', ">", f'metric = "{metric}"'))
    spec = load_sweep(path)

    def finals(values):
        table = trials_table({("+4/-1", 0.0): values})
        return table.assign(**{f"final_{metric}": table["final_team_reward"]})

    [done] = evaluate(spec, finals([20.0, 21.0, 22.0]))
    assert done.a == [] and done.verdict is Verdict.INCONCLUSIVE
    [running] = evaluate(spec, finals([20.0, 21.0]))
    assert running.verdict is Verdict.INTERIM


def test_pooled_sides_partial_sides_and_unfinished_trials(tmp_path):
    text = (claim("pooled", '{ rewards = "+4/-1" }', '{ rewards = ["+2/-1", "+1/-1"] }', ">")
            + claim("other metric", A, B, "<", 'metric = "follower_net_pickups"'))
    spec = spec_with(tmp_path, text)
    table = trials_table({("+4/-1", 0.0): [10, 11, 12], ("+4/-1", 0.2): [13, 14, 15],
                          ("+2/-1", 0.0): [1, 2, 3], ("+1/-1", 0.2): [4, 5, 6]})
    unfinished = trials_table({("+4/-1", 0.0): [100.0, 100.0]}, finished=False)
    pooled, other = evaluate(spec, pd.concat([table, unfinished]))
    assert sorted(pooled.a) == [10, 11, 12, 13, 14, 15] and sorted(pooled.b) == [1, 2, 3, 4, 5, 6]
    assert pooled.verdict is Verdict.REPRODUCED
    assert other.a == [-10.0, -11.0, -12.0] and other.b == [] and other.verdict is Verdict.INTERIM  # b's to come


CLAIM_MISTAKES = {
    "unknown expect": (claim("c", A, B, ">="), "claim[0].expect='>=' is invalid: '>' (a above b)"),
    "no margin for ~": (claim("c", A, B, "~"), "claim[0].margin=0.0 is invalid: a number > 0"),
    "margin for >": (claim("c", A, B, ">", "margin = 1"), "claim[0].margin=1 is invalid: given only with"),
    "unknown parameter": (claim("c", '{ reward = "+4/-1" }', B, ">"),
                          "claim[0].a='reward' is invalid: one of the listed parameters ['rewards', 'aux']"),
    "unlisted value": (claim("c", A, '{ aux = 0.5 }', ">"), "claim[0].b.aux=0.5 is invalid: one of [0.0, 0.2]"),
    "sides overlap": (claim("c", '{ aux = 0.0 }', '{ rewards = "+1/-1" }', ">"),
                      "is invalid: a side sharing no configuration with a"),
    "a constant side a": (claim("c", "3.0", B, ">"), "claim[0].a=3.0 is invalid: a table"),
    "two claims one name": (claim("c", A, B, ">") + claim("c", B, A, ">"), "claim[1].name='c' is invalid"),
    "unknown field": (claim("c", A, B, ">", 'expected = ">"'), "claim[0]: unknown field 'expected'"),
    "metric not summarised": (claim("c", A, B, ">", 'metric = "sps"'), "claim[0].metric='sps' is invalid"),
    "empty results": (claim("c", A, B, ">"), "results='' is invalid"),
}


@pytest.mark.parametrize("name", sorted(CLAIM_MISTAKES))
def test_each_claim_mistake_is_one_line_and_exit_code_2(tmp_path, capsys, name):
    text, expected = CLAIM_MISTAKES[name]
    top = 'results = ""\n' if name == "empty results" else ""
    path = tmp_path / "claims.toml"
    path.write_text(top + BASE + text)
    with pytest.raises(SweepError) as caught:
        load_sweep(path)
    assert expected in str(caught.value), str(caught.value)
    assert main(["sweep", "check", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err


def fake_trial(folder: Path, trial: str, rewards: str, aux: float, seed: int, values: list[float],
               total: int = 4096) -> None:
    """A trial folder as a sweep leaves it: Tune's params.json and the training log (every 2,048 steps)."""
    run = folder / trial / "run"
    run.mkdir(parents=True)
    (folder / trial / "params.json").write_text(json.dumps({"seed": seed, "rewards": rewards, "aux": aux}))
    rows = [{"stream": "train", "step": 2048 * (i + 1), "team_reward": v, "follower_net_pickups": -v,
             "wall_time_s": 1.0 + i, "sps": 2000.0} for i, v in enumerate(values)]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert rows[-1]["step"] <= total


def sweep_folder(tmp_path: Path, claims: str, results: Path) -> Path:
    folder = tmp_path / "runs" / "claims"
    folder.mkdir(parents=True)
    (folder / "sweep.toml").write_text(f'results = "{results}"\n' + BASE + claims)
    (folder / "workdir").write_text(str(tmp_path))
    return folder


def test_report_decides_claims_and_publish_keeps_finished_trials(tmp_path):
    results = tmp_path / "kept"
    more = '\n[[more_seeds]]\nseeds = [3]\nwhere = { rewards = "+4/-1", aux = 0.0 }\n'
    folder = sweep_folder(tmp_path, claim("optimism pays", A, B, ">", 'paper = "the paper says so"') + more, results)
    for seed, (hi, lo) in enumerate([(10, 1), (11, 2), (12, 3)]):
        fake_trial(folder, f"trial_a{seed}", "+4/-1", 0.0, seed, [hi - 1.0, hi + 1.0])
        fake_trial(folder, f"trial_b{seed}", "+1/-1", 0.0, seed, [lo + 1.0, lo - 1.0])
    fake_trial(folder, "trial_c0", "+2/-1", 0.2, 0, [5.0])  # unfinished: half of its steps
    fake_trial(folder, "trial_a3", "+4/-1", 0.0, 3, [100.0])  # a seed still running beside finished ones
    fake_trial(folder, "trial_b3", "+1/-1", 0.0, 3, [50.0])  # a seed the file does not give: not in the tables
    text, _ = write_report(folder)
    summary = pd.read_csv(folder / "summary.csv").set_index("configuration")
    assert summary.loc["rewards=+4/-1, aux=0.0", "final_team_reward_mean"] == pytest.approx(11.0)  # finished only
    assert tuple(summary.loc["rewards=+4/-1, aux=0.0", ["seeds", "finished"]]) == (4, 3)
    assert tuple(summary.loc["rewards=+1/-1, aux=0.0", ["seeds", "finished"]]) == (3, 3)  # not trial_b3
    assert summary.loc["rewards=+2/-1, aux=0.2", "final_team_reward_mean"] == pytest.approx(5.0)  # none finished
    assert "| optimism pays (a > b, team_reward) | the paper says so | rewards=+4/-1, aux=0.0: +11.00 (n=3) | " \
           "rewards=+1/-1, aux=0.0: +2.00 (n=3) | Welch | +9.00 [" in text
    assert "**reproduced**" in text and "- optimism pays: a: +10.00, +11.00, +12.00; b: +1.00, +2.00, +3.00" in text
    claims_csv = pd.read_csv(folder / "claims.csv")
    assert claims_csv.loc[0, "verdict"] == "reproduced" and claims_csv.loc[0, "n_a"] == 3
    where, count, published = publish_report(folder)
    assert (where, count) == (results, 6)  # the unfinished trial is not kept
    kept = pd.read_csv(results / "trials.csv")
    assert sorted(zip(kept["configuration"], kept["seed"]))[0] == ("rewards=+1/-1, aux=0.0", 0)
    curves = pd.read_csv(results / "curves.csv")
    assert set(curves["trial"]) == set(kept["trial"]) and len(curves) == 12
    assert {"step", "team_reward", "follower_net_pickups", "sps"} <= set(curves.columns)
    assert "**reproduced**" in published and (results / "report.md").read_text() == published
    spec = load_sweep(folder / "sweep.toml")
    assert committed_keys(spec, folder) == {(f"rewards={r}, aux=0.0", s) for r in ("+4/-1", "+1/-1") for s in range(3)}


def test_kept_results_fill_in_for_trials_a_new_machine_has_not_run(tmp_path):
    results = tmp_path / "kept"
    first = sweep_folder(tmp_path, claim("c", A, B, ">"), results)
    for seed in range(3):
        fake_trial(first, f"trial_a{seed}", "+4/-1", 0.0, seed, [9.0 + seed, 11.0 + seed])
    publish_report(first)
    # a new machine: a fresh sweep folder that has run only the other side, and one kept trial again (unfinished)
    second = tmp_path / "elsewhere" / "claims"
    second.mkdir(parents=True)
    (second / "sweep.toml").write_text((first / "sweep.toml").read_text())
    (second / "workdir").write_text(str(tmp_path))
    for seed in range(3):
        fake_trial(second, f"trial_b{seed}", "+1/-1", 0.0, seed, [1.0 + seed, 1.0 + seed])
    fake_trial(second, "trial_a0_again", "+4/-1", 0.0, 0, [3.0])
    text, _ = write_report(second)
    trials = pd.read_csv(second / "trials.csv")
    assert len(trials) == 6 and "trial_a0_again" not in set(trials["trial"])  # the kept finished trial wins
    assert "rewards=+4/-1, aux=0.0: +11.00 (n=3)" in text and "**reproduced**" in text
    # the sweep file alone reports what is kept
    file_text, _ = write_report(first / "sweep.toml")
    assert "3 of 18 trials have reported; 3 ran to the end" in file_text


def test_kept_trials_follow_the_seeds_the_file_gives(tmp_path):
    """Kept results of a seed the sweep file no longer gives a configuration (seeds moved to a ``[[more_seeds]]``
    table for one side only) are left out of the kept keys, the tables and the claims."""
    results = tmp_path / "kept"
    first = sweep_folder(tmp_path, claim("c", A, B, ">"), results)
    for seed in range(3):
        fake_trial(first, f"trial_a{seed}", "+4/-1", 0.0, seed, [9.0 + seed, 11.0 + seed])
        fake_trial(first, f"trial_b{seed}", "+1/-1", 0.0, seed, [1.0 + seed, 1.0 + seed])
    publish_report(first)
    every = {(f"rewards={r}, aux=0.0", s) for r in ("+4/-1", "+1/-1") for s in range(3)}
    assert committed_keys(load_sweep(first / "sweep.toml"), first) == every
    text = (first / "sweep.toml").read_text().replace("seeds = [0, 1, 2]", "seeds = [0, 1]")
    (first / "sweep.toml").write_text(text + '\n[[more_seeds]]\nseeds = [2]\nwhere = { rewards = "+4/-1" }\n')
    spec = load_sweep(first / "sweep.toml")
    assert committed_keys(spec, first) == every - {("rewards=+1/-1, aux=0.0", 2)}
    report, _ = write_report(first)
    assert "rewards=+1/-1, aux=0.0: +1.50 (n=2)" in report and "rewards=+4/-1, aux=0.0: +11.00 (n=3)" in report
