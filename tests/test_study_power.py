"""``colorgrid study power``: the participants an arm needs, checked against published tables (Cohen 1988, Table
2.4.1, for two groups; G*Power's paired t-test for one group of differences), and its bad input in one line."""

import json
import subprocess
import sys
import tomllib

import pandas as pd
import pytest

from server.study.config import load_study
from server.study.power import Comparison, participants_needed, read_trials, sample_size, t_test_power
from tests.conftest import ROOT, start_server, stop_server
from tests.test_examples import example
from tests.test_study import TOKEN, toml

WITHIN = ROOT / "studies" / "human_follower.toml"
FIRST_SEED = 2026
"""The walk-through's games start at this seed (``--first-seed``), so its pilot is the same on every run."""
BETWEEN = """
id = "two_followers"
title = "Two followers"
[factors]
follower = ["copy", "bayes"]
[defaults]
mode = "turn"
horizon = 3
[design]
assignment = "between"

[[pages]]
kind = "trials"
"""
LEADERS = ["astar", "person:slip=0.1,notice_delay=3"]


def write_pilot(folder, rows: list[dict], exclusions: list[dict] = ()):
    """A pilot's export: its ``trials`` (each row given a ``game_id`` if it has none) and its ``exclusions``."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = [{"game_id": f"g{i}", "ended": "complete", **row} for i, row in enumerate(rows)]
    pd.DataFrame(rows).to_parquet(folder / "trials.parquet")
    columns = {"participant": "string", "game_id": "string", "rule": "category"}
    pd.DataFrame(list(exclusions), columns=list(columns)).astype(columns).to_parquet(folder / "exclusions.parquet")
    return folder


def within_pilot(folder, exclusions: list[dict] = ()):
    """Six participants, each playing both leaders twice (and a practice game, not counted): their differences
    between the leaders are 0.1, 0.3, 0.2, 0.0, 0.4 and 0.2 (sd 0.1414...). Participant ``pI``'s trials are the games
    ``pI-LEADER-BASE`` (``p1-0-0.5``: beside the A* leader, the first of the two), its practice ``pI-practice``."""
    rows = []
    for i, diff in enumerate([0.1, 0.3, 0.2, 0.0, 0.4, 0.2]):
        pid = f"p{i}"
        rows.append({"participant": pid, "game_id": f"{pid}-practice", "kind": "practice",
                     "condition_leader": "astar", "stated_accuracy": 0.0})
        for base in (0.5, 0.7):  # two trials a level: the participant's mean at each level is taken
            rows.append({"participant": pid, "game_id": f"{pid}-0-{base}", "kind": "trial",
                         "condition_leader": LEADERS[0], "stated_accuracy": base + diff,
                         "probe_brier": None})  # no probes: no Brier score
            rows.append({"participant": pid, "game_id": f"{pid}-1-{base}", "kind": "trial",
                         "condition_leader": LEADERS[1], "stated_accuracy": base, "probe_brier": None})
    # an attempt lost with its server, played again (the trials above), and one still running: neither counts
    rows.append({"participant": "p2", "game_id": "p2-lost", "kind": "trial", "ended": "server_lost",
                 "condition_leader": LEADERS[0], "stated_accuracy": 0.0, "probe_brier": None})
    rows.append({"participant": "p3", "game_id": "p3-running", "kind": "trial", "ended": None,
                 "condition_leader": LEADERS[1], "stated_accuracy": 1.0, "probe_brier": None})
    return write_pilot(folder, rows, exclusions)


def between_pilot(folder):
    rows = [{"participant": f"c{i}", "kind": "trial", "condition_follower": "copy", "follower_net_pickups": v}
            for i, v in enumerate([1.0, 3.0, 2.0, 6.0])]
    rows += [{"participant": f"b{i}", "kind": "trial", "condition_follower": "bayes", "follower_net_pickups": v}
             for i, v in enumerate([5.0, 7.0, 4.0, 8.0])]
    return write_pilot(folder, rows)


@pytest.mark.parametrize("d, per_group", [(0.5, 64), (0.8, 26)])  # Cohen's 393 for d 0.2 is the normal
# approximation's; the exact t-test (statsmodels, G*Power) gives 394 there, and agrees with his table here
def test_between_participants_an_arm_needs_cohens_two_group_sample_size(d, per_group, tmp_path):
    path = tmp_path / "between.toml"
    path.write_text(BETWEEN)
    study = load_study(path)
    trials = pd.read_parquet(between_pilot(tmp_path / "pilot") / "trials.parquet")
    pooled = ((trials.groupby("condition_follower").follower_net_pickups.var(ddof=1)).mean()) ** 0.5  # equal groups
    report = sample_size(study, trials, Comparison("follower_net_pickups", d * pooled))
    (pair,) = report["pairs"]
    assert pair["effect_size"] == pytest.approx(d) and pair["sd"] == pytest.approx(pooled)
    assert pair["per_group"] == per_group and report["per_arm"] == per_group  # one condition a level: an arm
    assert report["participants"] == 2 * per_group


def test_within_participants_the_paired_test_gives_g_powers_34_for_dz_one_half(tmp_path):
    study = load_study(WITHIN)
    trials = read_trials(within_pilot(tmp_path / "pilot"))
    assert len(trials) == 24  # the practice, the lost attempt and the running one left out
    sd = pd.Series([0.1, 0.3, 0.2, 0.0, 0.4, 0.2]).std(ddof=1)
    report = sample_size(study, trials, Comparison("stated_accuracy", 0.5 * sd, "leader"))
    (pair,) = report["pairs"]
    assert pair["sd"] == pytest.approx(sd) and pair["effect_size"] == pytest.approx(0.5)
    assert pair["pilot_participants"] == 6 and pair["needed"] == 34  # G*Power, paired t-test, d_z 0.5: N = 34
    assert report["arms"] == 4 and report["per_arm"] == 9 and report["participants"] == 36  # each order equally often


@pytest.mark.parametrize("paired", [True, False])
def test_the_participants_needed_are_statsmodels_rounded_up_where_its_solver_converges(paired):
    import math
    import warnings

    from statsmodels.stats.power import TTestIndPower, TTestPower

    for effect in (0.2, 0.35, 0.5, 0.8, 1.2, 2.0):
        for alpha, power in ((0.05, 0.8), (0.01, 0.9)):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                solved = (TTestPower().solve_power(effect_size=effect, alpha=alpha, power=power) if paired else
                          TTestIndPower().solve_power(effect_size=effect, alpha=alpha, power=power, ratio=1.0))
            assert participants_needed(effect, alpha, power, paired) == math.ceil(solved), (effect, alpha, power)


def test_a_large_effect_on_a_handful_of_participants_has_its_power_right():
    """Where statsmodels' solver gives up (nan) or stops short (2 for d_z 10, whose power at 2 is 0.73), the power is
    the tests' own: checked against 40,000 simulated paired t-tests, and the fewest participants are where it first
    reaches 80%."""
    import numpy as np
    from scipy import stats

    rng = np.random.default_rng(0)
    for effect, n in ((10.0, 2), (10.0, 3), (8.0, 2), (3.0, 3)):
        draws = rng.normal(effect, 1.0, size=(40_000, n))
        simulated = float(np.mean(stats.ttest_1samp(draws, 0.0, axis=1).pvalue < 0.05))
        assert t_test_power(effect, n, 0.05, paired=True) == pytest.approx(simulated, abs=0.01), (effect, n)
    assert t_test_power(10.0, 2, 0.05, True) < 0.8 <= t_test_power(10.0, 3, 0.05, True)
    assert participants_needed(10.0, 0.05, 0.8, paired=True) == 3
    assert participants_needed(50.0, 0.05, 0.8, paired=True) == participants_needed(50.0, 0.05, 0.8, False) == 2


def test_a_difference_far_beyond_the_pilots_spread_is_planned_not_a_crash(tmp_path):
    study = load_study(WITHIN)
    trials = read_trials(within_pilot(tmp_path / "pilot"))
    sd = pd.Series([0.1, 0.3, 0.2, 0.0, 0.4, 0.2]).std(ddof=1)
    report = sample_size(study, trials, Comparison("stated_accuracy", 20 * sd, "leader"))
    (pair,) = report["pairs"]
    assert pair["needed"] == 2 and report["per_arm"] == 1 and report["participants"] == 4


def run(*args):
    return subprocess.run([sys.executable, "-m", "colorgrid_apps", "study", "power", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def test_the_command_prints_what_an_arm_needs_and_writes_json(tmp_path):
    pilot = within_pilot(tmp_path / "pilot")
    done = run(WITHIN, "--pilot", pilot, "--measure", "stated_accuracy", "--difference", 0.0707106781,
               "--json", tmp_path / "power.json")
    assert done.returncode == 0, done.stderr
    assert "within participants: paired t-test" in done.stdout and "d_z 0.500" in done.stdout
    assert "an arm needs 9 participants (36 in all over 4 arm(s))" in done.stdout
    assert "the study's quota is 12 per arm (48 in all): enough" in done.stdout
    assert "left out as excluded (the pilot's exclusions table; --keep-excluded keeps them): none of its 24 trials" \
        in done.stdout
    report = json.loads((tmp_path / "power.json").read_text())
    assert report["factor"] == "leader" and report["pairs"][0]["needed"] == 34
    assert report["left_out"]["trials"] == 0 and report["left_out"]["of"] == 24


EXCLUDED = [
    {"participant": "p3", "game_id": None, "rule": "failed_checks"},  # p3 excluded as a whole, and with it
    {"participant": "p3", "game_id": "p3-0-0.5", "rule": "away"},  # its trial that broke a rule of its own too
    {"participant": "p1", "game_id": "p1-0-0.5", "rule": "away"},  # one trial, two rules broken
    {"participant": "p1", "game_id": "p1-0-0.5", "rule": "idle"},
    {"participant": "p4", "game_id": "p4-1-0.7", "rule": "round_trip"},
]
"""The pilot's exclusions: p3 left out (its difference 0.0); p1's first A* trial (its difference becomes 1.0 - 0.6 =
0.4) and p4's second trial beside the person-like leader (1.0 - 0.5 = 0.5) left out."""


def test_the_pilots_excluded_trials_and_participants_are_left_out_and_counted_by_rule(tmp_path):
    pilot = within_pilot(tmp_path / "pilot", EXCLUDED)
    args = (WITHIN, "--pilot", pilot, "--measure", "stated_accuracy", "--difference", 0.0707106781)
    done = run(*args, "--json", tmp_path / "left_out.json")
    assert done.returncode == 0, done.stderr
    assert ("left out as excluded (the pilot's exclusions table; --keep-excluded keeps them): 6 of its 24 trials: the "
            "4 trial(s) of 1 participant(s) excluded as a whole (failed_checks 1) and 2 trial(s) excluded on their "
            "own (away 1, idle 1, round_trip 1)") in done.stdout, done.stdout
    report = json.loads((tmp_path / "left_out.json").read_text())
    assert report["left_out"] == {"trials": 6, "of": 24, "participants": 1, "participant_trials": 4,
                                  "participant_rules": {"failed_checks": 1}, "excluded_trials": 2,
                                  "trial_rules": {"away": 1, "idle": 1, "round_trip": 1}}
    (pair,) = report["pairs"]
    sd = pd.Series([0.1, 0.4, 0.2, 0.5, 0.2]).std(ddof=1)  # p0, p1, p2, p4, p5 as left
    assert pair["pilot_participants"] == 5 and pair["sd"] == pytest.approx(sd)
    assert pair["effect_size"] == pytest.approx(0.0707106781 / sd) and pair["needed"] > 34  # more spread: more needed
    # --keep-excluded: every counted trial, as if there were no exclusions (the G*Power case above)
    done = run(*args, "--keep-excluded", "--json", tmp_path / "kept.json")
    assert done.returncode == 0, done.stderr
    assert "the excluded trials kept (--keep-excluded): every counted trial of the pilot" in done.stdout
    report = json.loads((tmp_path / "kept.json").read_text())
    assert report["left_out"] is None and report["pairs"][0]["pilot_participants"] == 6
    assert report["pairs"][0]["needed"] == 34


@pytest.mark.parametrize("args, words", [
    (["--measure", "stated_acuracy", "--difference", "0.1"], "--measure 'stated_acuracy' is invalid: a numeric column"),
    (["--measure", "stated_accuracy", "--difference", "-0.1"], "--difference -0.1 is invalid: a positive number"),
    (["--measure", "stated_accuracy", "--difference", "a lot"], "argument --difference: invalid float value"),
    (["--measure", "stated_accuracy", "--difference", "0.1", "--power", "80"], "--power 80 is invalid"),
    (["--measure", "stated_accuracy", "--difference", "0.1", "--factor", "preset"], "--factor 'preset' is invalid"),
    (["--measure", "probe_brier", "--difference", "0.1"], "the pilot has 0 participant(s) for leader"),
    (["--measure", "follower_net_pickups", "--difference", "1"], "the pilot's trials table has no column"),
])
def test_bad_input_is_one_line_and_exit_code_2(args, words, tmp_path):
    done = run(WITHIN, "--pilot", within_pilot(tmp_path / "pilot"), *args)
    assert done.returncode == 2 and done.stdout == "", done
    assert len(done.stderr.strip().splitlines()) == 1 and words in done.stderr, done.stderr


def test_a_pilot_folder_without_an_export_or_a_single_participant_is_refused_in_one_line(tmp_path):
    done = run(WITHIN, "--pilot", tmp_path / "nowhere", "--measure", "stated_accuracy", "--difference", "0.1")
    assert done.returncode == 2 and "no trials.parquet there" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    one = write_pilot(tmp_path / "one", [{"participant": "p0", "kind": "trial", "condition_leader": level,
                                          "stated_accuracy": 0.5} for level in LEADERS])
    done = run(WITHIN, "--pilot", one, "--measure", "stated_accuracy", "--difference", "0.1")
    assert done.returncode == 2 and "the pilot has 1 participant(s)" in done.stderr, done.stderr
    (one / "exclusions.parquet").unlink()  # an export without its exclusions: refused, unless they are to be kept
    done = run(WITHIN, "--pilot", one, "--measure", "stated_accuracy", "--difference", "0.1")
    assert done.returncode == 2 and "no exclusions.parquet there" in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    done = run(WITHIN, "--pilot", one, "--measure", "stated_accuracy", "--difference", "0.1", "--keep-excluded")
    assert done.returncode == 2 and "the pilot has 1 participant(s)" in done.stderr, done.stderr


def test_the_documented_walk_through_on_the_scripted_stand_ins_export(tmp_path):
    """docs/STUDIES.md's steps, on short games: the stand-in (a script, not a person) takes part in the study as three
    participants, the study is exported, and the command plans on that export."""
    data = tomllib.loads(WITHIN.read_text())
    data["defaults"]["horizon"] = 20
    data["factors"]["probes"] = ["none", "steps:5"]
    for page in data["pages"]:
        if page["kind"] == "practice":
            page["game"].update(horizon=5, probes="steps:2")
    path = tmp_path / "human_follower.toml"
    path.write_text(toml(data))
    # Fixed boards (``FIRST_SEED``): from the clock's seeds, the three stand-ins' differences between the leaders came
    # out all equal in one of the suite's runs 43-50, and the command then rightly refused a pilot without spread.
    server = start_server(tmp_path, "--first-seed", str(FIRST_SEED), command=("study", "run", str(path)),
                          env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    try:
        stand_in = example("scripted_assistant")
        assert [stand_in.take_part(server.ws_url, f"stand-in-{i}") for i in range(3)] == [5, 5, 5]
    finally:
        stop_server(server)
    out = tmp_path / "stand_in_data"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "study", "export", str(path), "--replays-dir",
                           str(server.replays_dir), "--out", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    trials = pd.read_parquet(out / "trials.parquet")
    assert (trials.kind == "trial").sum() == 12 and trials.participant.nunique() == 3
    done = run(path, "--pilot", out, "--measure", "team_score", "--difference", 2, "--json", tmp_path / "p.json")
    assert done.returncode == 0, done.stderr
    report = json.loads((tmp_path / "p.json").read_text())
    (pair,) = report["pairs"]
    exclusions = pd.read_parquet(out / "exclusions.parquet")  # left out as the documented analysis leaves them
    left_out = set(exclusions.participant[exclusions.game_id.isna()])
    trials = trials[(trials.kind == "trial") & ~trials.game_id.isin(exclusions.game_id)
                    & ~trials.participant.isin(left_out)]
    assert report["left_out"]["trials"] == 12 - len(trials) and "left out as excluded" in done.stdout
    mine = trials.groupby(["participant", "condition_leader"], observed=True).team_score.mean()
    differences = mine.unstack()[LEADERS[0]] - mine.unstack()[LEADERS[1]]
    assert pair["pilot_participants"] == trials.participant.nunique()
    assert pair["sd"] == pytest.approx(differences.std(ddof=1))
    assert f"an arm needs {report['per_arm']} participants" in done.stdout and report["per_arm"] >= 1
