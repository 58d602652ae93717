"""Claims declared before the data: ``sweep run --local`` records each claim's digest before its first trial, the
report reads the record (before data, after data, not recorded), and a claim declared or changed after trials of
its configurations finished is held as exploratory, never reproduced. Also the other side of a ``~`` claim: a
difference beyond the margin is shown only by the 1 - 2 alpha interval lying wholly outside it."""

import pandas as pd
import pytest
from scipy import stats

from train.sweep.claims import Verdict, evaluate
from train.sweep.declared import DECLARED_FILE, Declared, declare, digest, read_record
from train.sweep.local import run_local
from train.sweep.report import write_report
from train.sweep.spec import load_sweep
from tests.sweep_files import sweep_file
from tests.test_sweep_claims import A, B, claim, spec_with, trials_table


def test_the_digest_is_what_decides_a_claim(tmp_path):
    same = spec_with(tmp_path, claim("one", A, B, ">")).claims[0]
    spelled = spec_with(tmp_path, claim("renamed", '{ aux = 0, rewards = "+4/-1" }', B, ">",
                                        'paper = "other words"')).claims[0]
    assert digest(same) == digest(spelled)  # key order, 0 or 0.0, name and words: the same claim
    for changed in (claim("one", A, B, "<"), claim("one", A, '{ rewards = "+2/-1", aux = 0.0 }', ">"),
                    claim("one", A, B, ">", 'metric = "follower_net_pickups"'), claim("one", A, "0.0", ">")):
        assert digest(spec_with(tmp_path, changed).claims[0]) != digest(same)


def test_a_claim_recorded_before_its_trials_is_decided_and_one_after_them_is_exploratory(tmp_path):
    results = tmp_path / "kept"
    spec = spec_with(tmp_path, claim("early", A, B, ">"), top=f'results = "{results}"\n')
    table = trials_table({("+4/-1", 0.0): [10.0, 11.0, 12.0], ("+1/-1", 0.0): [0.0, 1.0, 2.0]})
    [unrecorded] = evaluate(spec, table)
    assert unrecorded.declared is Declared.UNRECORDED and unrecorded.verdict is Verdict.REPRODUCED
    assert declare(spec, tmp_path / "run", when="2026-01-01T00:00:00+00:00") == 1
    assert declare(spec, tmp_path / "run") == 0  # recorded once
    [before] = evaluate(spec, table)
    assert before.declared is Declared.BEFORE and before.verdict is Verdict.REPRODUCED
    # the trials are kept now; a claim added and one changed after them are exploratory, whatever the test says
    table.to_csv(results / "trials.csv", index=False)
    later = spec_with(tmp_path, claim("early", A, B, ">") + claim("late", A, '{ rewards = "+2/-1", aux = 0.0 }',
                                                                   "<"), top=f'results = "{results}"\n')
    with_late = pd.concat([table, trials_table({("+2/-1", 0.0): [20.0, 21.0, 22.0]})], ignore_index=True)
    early, late = evaluate(later, with_late)
    assert (early.declared, early.verdict) == (Declared.BEFORE, Verdict.REPRODUCED)
    assert late.declared is Declared.AFTER and late.verdict is Verdict.EXPLORATORY and late.p_adjusted < 0.05
    assert declare(later, tmp_path / "run") == 1  # the late claim is recorded, with the trials it came after
    record = read_record(results)
    assert list(record["claim"]) == ["early", "late"] and list(record["trials_finished"]) == [0, 3]
    assert evaluate(later, with_late)[1].verdict is Verdict.EXPLORATORY


def test_sweep_run_local_records_the_claims_before_the_first_trial(tmp_path):
    results = tmp_path / "kept"
    claims = '\n[[claim]]\nname = "a larger step"\na = { "ppo.lr" = 1e-3 }\nb = { "ppo.lr" = 1e-4 }\nexpect = ">"\n'
    path = sweep_file(tmp_path, "declared", '[params]\n"ppo.lr" = [1e-4, 1e-3]', seeds="[0, 1]",
                      top=f'results = "{results}"', tables=claims)
    folder = tmp_path / "out"
    assert run_local(load_sweep(path, out=folder), processes=2) == 0
    record = read_record(results)
    assert list(record["claim"]) == ["a larger step"] and list(record["trials_finished"]) == [0]
    assert list(record["source"]) == ["sweep run"]
    text, _ = write_report(folder)
    assert "| before data |" in text
    # the direction turned after the trials finished: recorded with them, and exploratory
    path.write_text(path.read_text().replace('expect = ">"', 'expect = "<"'))
    assert run_local(load_sweep(path, out=folder), processes=2) == 0  # every trial finished: none runs
    assert list(read_record(results)["trials_finished"]) == [0, 4]
    text, _ = write_report(folder)
    assert "| after data | **exploratory** |" in text and "**reproduced**" not in text
    assert (results / DECLARED_FILE).is_file() and not (folder / DECLARED_FILE).exists()


@pytest.mark.parametrize("a, b, margin, verdict", [
    ([3.0, 3.4, 3.8, 4.2, 4.6], [0.0, 0.2, -0.2, 0.1, -0.1], 2.5, Verdict.NOT_REPRODUCED),  # wholly beyond
    ([3.0, 3.4, 3.8, 4.2, 4.6], [0.0, 0.2, -0.2, 0.1, -0.1], 3.5, Verdict.INCONCLUSIVE),  # beyond, the interval not
])
def test_a_difference_beyond_the_margin_needs_the_interval_wholly_outside_it(tmp_path, a, b, margin, verdict):
    spec = spec_with(tmp_path, claim("same", A, B, "~", f"margin = {margin}"))
    [o] = evaluate(spec, trials_table({("+4/-1", 0.0): a, ("+1/-1", 0.0): b}))
    welch = stats.ttest_ind(a, b, equal_var=False)
    interval = welch.confidence_interval(0.90)  # 1 - 2 alpha at alpha 0.05: the interval the one-sided tests read
    assert welch.pvalue < 0.001 and abs(o.difference) > margin  # the old rule: not reproduced, both times
    assert (o.low, o.high) == pytest.approx((interval.low, interval.high)) and o.confidence == pytest.approx(0.9)
    assert (interval.low > margin) == (o.p_outside < 0.05) == (verdict is Verdict.NOT_REPRODUCED)
    one_sided = stats.ttest_ind(a, [v + margin for v in b], equal_var=False, alternative="greater")
    assert o.p_outside == pytest.approx(one_sided.pvalue) and o.verdict is verdict
