"""The measures of a person in the follower seat, beside AI followers watching the same history: golden values, a
recorded game counted by hand, and ``colorgrid replay rescore``."""

import json
import re
import math
import subprocess
import sys

import numpy as np
import pytest

from colorgrid.config import FOLLOWER, LEADER, EnvConfig
from colorgrid.env import BatchEnv
from colorgrid.policies import make_policy
from colorgrid.replay import Replay, load, save, verify
from colorgrid.step_inputs import StepInputs
from colorgrid.replay.branch import branch, watch
from colorgrid.evaluate import catch_lags, switch_lags
from colorgrid.replay.human_follower import (
    answer_distribution, brier, human_follower_report, log_loss, person_measures,
)

CONFIG = EnvConfig(horizon=40, switch_prob=0.15)


def test_golden_values_of_an_answer_its_log_loss_and_brier_score():
    probs = answer_distribution(2, 0.6, 3)
    assert probs.tolist() == pytest.approx([0.2, 0.2, 0.6])
    assert log_loss(probs, 2) == pytest.approx(-math.log(0.6)) and log_loss(probs, 0) == pytest.approx(-math.log(0.2))
    assert brier(probs, 2) == pytest.approx(0.04 + 0.04 + 0.16)  # (0.2)^2 + (0.2)^2 + (0.6 - 1)^2
    assert brier(probs, 0) == pytest.approx(0.64 + 0.04 + 0.36)
    assert log_loss(answer_distribution(0, 1.0, 3), 1) == pytest.approx(-math.log(1e-6))  # clipped, as eval


def test_switch_lags_count_the_steps_until_the_belief_is_right_and_skip_switches_never_caught():
    goal = np.array([0, 0, 1, 1, 1, 1, 2, 2, 0, 0])[:, None]
    right = np.array([1, 1, 0, 0, 1, 1, 0, 0, 0, 1], dtype=bool)[:, None]
    # the switch at step 2 is caught after 2 steps; the one at 6 never (the next comes first); the one at 8 after 1
    assert catch_lags(right, goal).tolist() == [2, 1]
    probs = np.eye(3)[np.where(right[:, 0], goal[:, 0], (goal[:, 0] + 1) % 3)][:, None, :]
    assert switch_lags(probs, goal).tolist() == [2, 1]  # the AI's lags: the same rule on its argmax


def recorded_game(seed: int = 7) -> Replay:
    """A game of a person in the follower seat beside A*, as the server records it: the person moves at random and
    states the goal two steps late (so every switch is caught after exactly 2 steps, when the next one is not
    sooner); three probes answered, one with the right color."""
    env = BatchEnv(CONFIG, num_envs=1, seed=seed, autoreset=False)
    obs, _ = env.reset()
    leader = make_policy("astar", role="leader")
    leader.reset(CONFIG, 1, LEADER, seed=seed)
    last, rng = StepInputs.begin(CONFIG, 1), np.random.default_rng(seed)
    actions, goals, rewards, team, picked, switched, hashes = [], [], [], [], [], [], [env.state.state_hash(0)]
    for t in range(CONFIG.horizon):
        goals.append(int(env.state.goal[0]))
        lead = leader.act(last.agent_input(obs, LEADER, env.penalty_coef, env.state.goal.copy())).actions[0]
        joint = np.array([[int(lead), int(rng.integers(4))]])
        obs, _, _, _, info = env.step(joint)
        last.record(joint, info)
        actions.append(joint[0].tolist())
        rewards.append([float(x) for x in info["block_reward"][0]])
        team.append(float(info["team_reward"][0]))
        picked.append([int(x) for x in info["picked_color"][0]])
        switched.append(bool(info["goal_switched"][0]))
        hashes.append(env.state.state_hash(0))
    stated = [None, None] + goals[:-2]
    probes = [{"id": i, "step": s, "trigger": "steps", "asked_ms": 1000.0 * s, "status": "answered",
               "color": c, "confidence": conf, "answered_step": s, "t_client": 0.0, "answered_ms": 1000.0 * s + 800,
               "response_ms": 800.0, "refused": 0}
              for i, (s, c, conf) in enumerate([(5, goals[5], 0.9), (15, (goals[15] + 1) % 3, 0.6),
                                                (30, (goals[30] + 2) % 3, 0.34)])]
    probes.append({"id": 3, "step": 35, "trigger": "steps", "asked_ms": 35000.0, "status": "unanswered",
                   "color": None, "confidence": None, "answered_step": None, "t_client": None, "answered_ms": None,
                   "response_ms": None, "refused": 0})
    return Replay(config=CONFIG, seed=seed, source="play", agents={"leader": {"policy": "astar"},
                                                                    "follower": {"policy": "human"}},
                  actions=actions, goal=goals, block_reward=rewards, team_reward=team, picked_color=picked,
                  goal_switched=switched, state_hashes=hashes, key_events=[],
                  stated_beliefs={"follower": stated}, probes=probes,
                  belief_events=[{"color": c, "via": "key", "step": t, "t_client": 0.0, "t_server": 0.0}
                                 for t, c in enumerate(stated) if c is not None],
                  meta={"seat": "follower", "goal_view": "hidden", "probes": "steps:5,15,30,35", "mode": "turn"})


def test_the_measures_of_a_recorded_game_equal_a_count_by_hand(tmp_path):
    path = save(recorded_game(), tmp_path / "person.replay.json")
    replay = load(path)
    assert verify(replay).ok  # the stated beliefs and probes travel in the checksummed file
    goal, stated = replay.goal, replay.stated_beliefs["follower"]
    assert sum(goal[t] != goal[t - 1] for t in range(1, len(goal))) >= 3, "the seed gives several switches"
    said = [t for t in range(len(goal)) if stated[t] is not None]
    right = sum(stated[t] == goal[t] for t in said)
    lags = []  # by hand: for each switch, the steps until the stated color is the new goal (before the next switch)
    for t in range(1, len(goal)):
        if goal[t] != goal[t - 1]:
            k = 0
            while t + k < len(goal) and goal[t + k] == goal[t] and stated[t + k] != goal[t]:
                k += 1
            if t + k < len(goal) and goal[t + k] == goal[t]:
                lags.append(k)
    c = [0.9, 0.6, 0.34]  # the three answers: right, wrong, wrong
    losses = [-math.log(c[0]), -math.log((1 - c[1]) / 2), -math.log((1 - c[2]) / 2)]
    briers = [(1 - c[0]) ** 2 + 2 * ((1 - c[0]) / 2) ** 2,
              c[1] ** 2 + (1 - (1 - c[1]) / 2) ** 2 + ((1 - c[1]) / 2) ** 2,
              c[2] ** 2 + (1 - (1 - c[2]) / 2) ** 2 + ((1 - c[2]) / 2) ** 2]
    final = replay.final()
    m = person_measures(replay, "follower")
    assert m["stated_steps"] == len(said) == 38 and m["accuracy"] == pytest.approx(right / len(said))
    assert m["switch_lags"] == lags and set(lags) <= {0, 1, 2} and 2 in lags
    assert m["switches"] == sum(goal[t] != goal[t - 1] for t in range(1, len(goal)))
    assert m["probes_asked"] == 4 and m["probes_answered"] == 3 and m["probe_accuracy"] == pytest.approx(1 / 3)
    assert m["log_loss"] == pytest.approx(sum(losses) / 3) and m["brier"] == pytest.approx(sum(briers) / 3)
    assert m["median_response_ms"] == 800.0
    assert m["net_pickups"] == final["follower_goal_pickups"] - final["follower_wrong_pickups"]
    assert m["wrong_pickups"] == sum(1 for t, p in enumerate(replay.picked_color) if p[FOLLOWER] not in (-1, goal[t]))


def test_an_ai_follower_watching_the_persons_seat_forms_the_beliefs_it_would_in_a_branch(tmp_path):
    replay = recorded_game()
    watched = watch(replay, "bayes", FOLLOWER)
    assert len(watched) == replay.num_steps and all(abs(sum(b) - 1) < 1e-3 for b in watched)
    later = branch(replay, 25, "bayes")  # it watches the first 25 steps there too, then acts
    assert later.goal_probs["follower"][:25] == watched[:25]
    assert watch(replay, "copy", FOLLOWER) is None  # a follower without a belief
    save(replay, tmp_path / "person.replay.json")
    report = human_follower_report([tmp_path / "person.replay.json"], ["bayes", "copy"])
    person, bayes = report["measures"]["person"], report["measures"]["bayes"]
    accuracy = np.mean([int(np.argmax(b)) == g for b, g in zip(watched, replay.goal)])
    assert bayes["accuracy_all_steps"] == pytest.approx(accuracy) and report["measures"]["copy"] is None
    assert person["accuracy"] == pytest.approx(person_measures(replay, "follower")["accuracy"])
    assert report["paired_difference"]["bayes"]["accuracy"]["mean"] == pytest.approx(
        bayes["accuracy"] - person["accuracy"])


def test_rescore_prints_the_people_beside_the_followers_and_writes_json(tmp_path):
    save(recorded_game(), tmp_path / "games" / "person.replay.json")
    out = tmp_path / "rescore.json"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "replay", "rescore", str(tmp_path / "games"),
                           "--follower", "bayes-people", "bayes", "--json", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "1 recorded game(s) with a person in the follower seat" in done.stdout
    assert "belief accuracy (stated steps)" in done.stdout and "probe Brier score" in done.stdout
    assert "bayes - person (paired over games)" in done.stdout
    report = json.loads(out.read_text())
    person = report["human_follower"]["measures"]["person"]
    assert person["stated_steps"] == 38 and person["probes_answered"] == 3
    bayes = report["human_follower"]["measures"]["bayes"]
    assert bayes["net_pickups"]["mean"] == report["net_pickups"]["bayes"]["mean"]  # rescore's, in the person's seat


def shown_game(seed: int, study_kind: str | None = None) -> Replay:
    """A game of the person with the goal shown (a control) and every probe answered right; with ``study_kind``, a
    study's game of that kind."""
    replay = recorded_game(seed)
    for probe in replay.probes:
        if probe["status"] == "answered":
            probe.update(color=replay.goal[probe["step"]], confidence=0.9)
    replay.meta["goal_view"] = "shown"
    if study_kind is not None:
        replay.meta["study"] = {"study": "human_follower", "participant": "p-1", "kind": study_kind}
    return replay


def test_rescore_reports_practice_and_goal_shown_games_apart_never_pooled_with_the_persons(tmp_path):
    games = tmp_path / "games"
    save(recorded_game(), games / "hidden.replay.json")
    save(shown_game(8), games / "shown.replay.json")
    save(shown_game(9, "practice"), games / "practice.replay.json")
    save(shown_game(10, "practice"), games / "practice2.replay.json")
    out = tmp_path / "rescore.json"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "replay", "rescore", str(games),
                           "--follower", "bayes", "--json", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())["human_follower"]
    person = report["measures"]["person"]  # the hidden-goal game alone: one probe of three right, as counted by hand
    assert person["games"] == 1 and person["probe_accuracy"] == pytest.approx(1 / 3) and person["probes_answered"] == 3
    assert [g["game"].rsplit("/", 1)[1] for g in report["games"]] == ["hidden.replay.json"]
    apart = report["set_apart"]
    assert set(apart) == {"practice", "goal_shown"}
    assert apart["practice"]["measures"]["person"]["games"] == 2
    assert apart["goal_shown"]["measures"]["person"]["games"] == 1
    assert apart["practice"]["measures"]["person"]["probe_accuracy"] == 1.0
    # the followers' open-loop pickups too: the hidden-goal game pooled alone, each kind apart with its own figures
    rescored = json.loads(out.read_text())
    assert [g.rsplit("/", 1)[1] for g in rescored["games"]] == ["hidden.replay.json"]
    assert {kind: len(part["games"]) for kind, part in rescored["set_apart"].items()} == {"practice": 2,
                                                                                          "goal_shown": 1}
    assert rescored["net_pickups"]["bayes"]["mean"] == rescored["per_game"]["bayes"][0]
    practice_nets = rescored["set_apart"]["practice"]["per_game"]["bayes"]
    assert rescored["set_apart"]["practice"]["net_pickups"]["bayes"]["mean"] == pytest.approx(np.mean(practice_nets))
    assert apart["practice"]["measures"]["bayes"]["net_pickups"]["mean"] == pytest.approx(np.mean(practice_nets))
    assert report["measures"]["bayes"]["pickups_games"] == 1 and apart["practice"]["measures"]["bayes"][
        "pickups_games"] == 2
    text = done.stdout
    pooled, people = text.split("with a person in the follower seat")[0], text[text.index("1 recorded game(s) with"):]
    assert pooled.startswith("1 recorded games, each leader's moves replayed open-loop with each follower")
    assert "set apart, not pooled above: 2 practice game(s) of a study\n2 recorded games, each" in pooled
    assert "set apart, not pooled above: 1 game(s) that showed the person the goal (a control)\n1 recorded games" \
           in pooled
    assert "1 recorded game(s) with a person in the follower seat, the goal hidden" in text
    assert "set apart, not in the person's figures above: 2 practice game(s) of a study" in people
    assert "set apart, not in the person's figures above: 1 game(s) that showed the person the goal" in people
    assert "nan" not in text  # one game has no interval
    first = people.split("set apart")[0]
    net = next(line for line in first.splitlines() if line.startswith("net pickups "))
    assert "±" not in net, net
    practice = people.split("practice game(s) of a study")[1].split("set apart")[0]
    assert re.search(r"probe answers right\s+100\.0%", practice) and "net pickups " in practice


def test_only_games_set_apart_still_report_them_and_say_the_person_has_no_figures(tmp_path):
    save(shown_game(9, "practice"), tmp_path / "practice.replay.json")
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "replay", "rescore", str(tmp_path),
                           "--follower", "bayes"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "no recorded game of a person in the follower seat with the goal hidden" in done.stdout
    assert "1 practice game(s) of a study" in done.stdout and "nan" not in done.stdout
    assert done.stdout.startswith("no recorded game to pool: every game rescored is set apart below\n\n"
                                  "set apart, not pooled above: 1 practice game(s) of a study\n"
                                  "1 recorded games, each leader's moves replayed")
    follower = next(line for line in done.stdout.splitlines() if line.startswith("bayes "))
    assert "±" not in follower, follower  # rescore's own table: one game, no interval
