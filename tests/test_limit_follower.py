"""The information limit (``bayes-limit``): a known posterior by hand, an exact model of the leader, at least the
population-average follower's accuracy on fixed episodes, the command line, and the script that draws the picture."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from colorgrid.config import EnvConfig
from colorgrid.evaluate import evaluate
from colorgrid.policies import PersonStyle, make_policy
from colorgrid.policies.limit import LimitFollower, goal_transition, initial_joint, leader_step, notice_table
from colorgrid.rollout import run_episodes
from colorgrid_apps.cli import main

ROOT = Path(__file__).resolve().parents[1]
UP, DOWN = 0, 1


def plans(*moves):
    """``[1, C, 4]`` move probabilities: the leader pursuing color ``c`` takes ``moves[c]``."""
    return np.eye(4)[list(moves)][None]


def goal_marginal(joint):
    return joint.sum(axis=(2, 3, 4, 5))[0] / joint.sum()


def step(joint, style, moves, action, last=-1):
    return leader_step(joint, plans(*moves), np.array([action]), np.array([last]), np.array([False]), style)


def test_a_slip_leaves_a_known_posterior_by_hand():
    style = PersonStyle(slip=0.25)
    joint = step(initial_joint(1, style, 3), style, (UP, DOWN, UP), UP)
    # under goals 0 and 2 the plan was up: 0.75 + 0.25 / 4; under goal 1 only a slip: 0.25 / 4
    assert goal_marginal(joint) == pytest.approx(np.array([0.8125, 0.0625, 0.8125]) / 1.6875)
    after = goal_marginal(goal_transition(joint / joint.sum(), 0.02))
    assert after == pytest.approx([0.98 * 0.8125 / 1.6875 + 0.01 * 0.875 / 1.6875,
                                   0.98 * 0.0625 / 1.6875 + 0.01 * 1.625 / 1.6875,
                                   0.98 * 0.8125 / 1.6875 + 0.01 * 0.875 / 1.6875])


def test_a_hesitation_repeats_the_last_move_by_hand():
    style = PersonStyle(hesitate=0.2, slip=0.1)
    joint = step(initial_joint(1, style, 3), style, (UP, DOWN, DOWN), UP, last=DOWN)
    # up repeats nothing: 0.1 / 4 + 0.7 under goal 0, 0.1 / 4 under goals 1 and 2
    assert goal_marginal(joint) == pytest.approx(np.array([0.725, 0.025, 0.025]) / 0.775)
    joint = step(initial_joint(1, style, 3), style, (UP, DOWN, DOWN), DOWN, last=DOWN)
    # down is the last move: 0.1 / 4 + 0.2 under goal 0, and + 0.7 under goals 1 and 2
    assert goal_marginal(joint) == pytest.approx(np.array([0.225, 0.925, 0.925]) / 2.075)


def test_a_late_leader_says_nothing_of_a_switch_until_it_notices_it():
    """Known goal 0, then a switch to 1 or 2 with even odds: a leader two steps late keeps walking to color 0, which
    leaves the posterior as it was; when it turns, its move rules out goal 0 (a leader without a delay: at once)."""
    style, C = PersonStyle(notice_delay=2), 3
    joint = np.zeros_like(initial_joint(1, style, C))
    joint[0, 0, 0, 0, C, 0] = 1.0
    joint = goal_transition(joint, 0.5)  # goal 0 with 1/2, each other color with 1/4; its target still 0
    for _ in range(2):
        joint = step(joint, style, (UP, DOWN, DOWN), UP)
        assert goal_marginal(joint) == pytest.approx([0.5, 0.25, 0.25])
    joint = step(joint, style, (UP, DOWN, DOWN), DOWN)
    assert goal_marginal(joint) == pytest.approx([0.0, 0.5, 0.5])
    prompt = PersonStyle()
    early = np.zeros_like(initial_joint(1, prompt, C))
    early[0, 0, 0, 0, C, 0] = 1.0
    early = step(goal_transition(early, 0.5), prompt, (UP, DOWN, DOWN), UP)
    assert goal_marginal(early) == pytest.approx([1.0, 0.0, 0.0])


def test_a_delay_range_is_drawn_for_each_switch():
    table = notice_table(PersonStyle(notice_delay=0, notice_delay_max=2), 3)  # [goal, target, pending, target', pending']
    fresh = table[1, 0, 0]  # goal 1, target 0, nothing pending
    assert fresh[1, 0] == pytest.approx(1 / 3)  # a delay of 0: it turns at once
    assert fresh[0, 1] == pytest.approx(1 / 3) and fresh[0, 2] == pytest.approx(1 / 3)
    assert table[1, 0, 1, 1, 0] == 1.0 and table[1, 0, 2, 0, 1] == 1.0  # the count runs out, then it turns
    assert table[0, 0, 2, 0, 0] == 1.0  # the goal switched back: nothing pending


@pytest.mark.parametrize("leader", [
    "person:slip=0.1,notice_delay=2,notice_delay_max=4,wrong_pickup=0.05,hesitate=0.1,detour=0.05,detour_len=3",
    "person:rationality=2.0,detour=0.1,detour_len=2,wrong_pickup=0.03",
    "population:people#held_out",
])
def test_the_model_is_the_leaders_own_every_action_has_a_chance(leader):
    follower = make_policy("bayes-limit")
    batch = run_episodes(EnvConfig(horizon=64), make_policy(leader, "leader"), follower, 12, 5)
    assert follower.surprises == 0
    probs = batch.goal_probs[1]
    assert np.allclose(probs.sum(axis=2), 1.0)
    truth = np.take_along_axis(probs, batch.goal[:, :, None], axis=2)
    assert (truth > 0).all()  # the true goal is never ruled out


class ToldAStar(LimitFollower):
    """A limit follower told the wrong model: that its leader is A*."""

    def see_team(self, policies):
        super().see_team([make_policy("astar", "leader"), *policies[1:]])


def test_a_wrong_model_is_surprised():
    follower = ToldAStar()
    run_episodes(EnvConfig(horizon=64), make_policy("person:slip=0.3", "leader"), follower, 6, 5)
    assert follower.surprises > 0


@pytest.mark.parametrize("leader", ["person:notice_delay=4,slip=0.15",
                                    "person:notice_delay=2,notice_delay_max=6,hesitate=0.2,wrong_pickup=0.04"])
def test_given_the_true_model_it_reads_the_goal_at_least_as_well_as_the_population_average_follower(leader):
    """On a fixed set of episodes (seeds 100-129, members not in the shipped population)."""
    config = EnvConfig(horizon=64)
    limit, people, plain = (evaluate(config, leader, name, 30, 100)["agents"]["follower"]["belief"]
                            for name in ("bayes-limit", "bayes-people", "bayes"))
    assert limit["accuracy"] >= max(people["accuracy"], plain["accuracy"])
    assert limit["log_loss"] < min(people["log_loss"], plain["log_loss"])


def test_colorgrid_eval_names_it(capsys):
    assert main(["eval", "--leader", "person:slip=0.1", "--compare", "bayes", "bayes-limit", "--episodes", "2",
                 "--set", "horizon=32"]) == 0
    out = capsys.readouterr().out
    assert "person:slip=0.1 + bayes-limit" in out and "follower belief accuracy" in out
    assert main(["eval", "--leaders", "population:people#held_out", "--compare", "bayes", "bayes-limit",
                 "--episodes", "2", "--workers", "1", "--set", "horizon=32"]) == 0
    out = capsys.readouterr().out
    assert "bayes-limit" in out and "wanderer" in out


@pytest.mark.parametrize("args, words", [
    (["--leader", "random"], "the leader 'random' has none it can be given"),
    (["--leader", "astar", "--team", "2:1"], "bayes-limit models one leader; this team has 2"),
    (["--leader", "person:base=ippo-leader,slip=0.1"],
     "a person around 'ippo-leader' has none it can be given (its base's own moves have no model)"),
])
def test_colorgrid_eval_refuses_a_leader_without_a_model_in_one_line(capsys, args, words):
    assert main(["eval", *args, "--follower", "bayes-limit", "--episodes", "2", "--set", "horizon=16"]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1


def test_the_limit_takes_no_parameters_and_exits_2():
    result = subprocess.run([sys.executable, "-m", "colorgrid_apps", "eval", "--follower", "bayes-limit:lapse=0.2",
                             "--episodes", "2"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 2
    assert "takes no parameters" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_outside_an_evaluation_it_says_it_needs_its_leaders_model():
    from colorgrid.policies.base import AgentInput

    config = EnvConfig()
    follower = make_policy("bayes-limit")
    follower.reset(config, 1, 1)
    inp = AgentInput(np.zeros((1, config.num_colors + 2, config.height, config.width), np.uint8),
                     np.zeros((1, config.num_colors), np.float32), np.ones(1, bool), np.zeros(1, np.float32),
                     np.full((1, 2), -1), np.full((1, 2), -1))
    with pytest.raises(ValueError, match="must be given its leader's model"):
        follower.act(inp)


def test_after_switch_counts_by_hand():
    sys.path.insert(0, str(ROOT / "bench"))
    from beside_people import after_switch

    goal = np.array([0, 0, 1, 1, 1, 2, 2])[:, None]  # switches before steps 2 and 5
    right = np.array([1, 1, 0, 1, 1, 0, 0], dtype=bool)[:, None]
    counts = after_switch(right, goal, 3)
    # k = 0: steps 2 and 5 (both wrong); k = 1: steps 3 and 6 (right, wrong); k = 2: step 4 (right; 7 is past the end)
    assert counts.tolist() == [[0, 1, 1, 0], [2, 2, 1, 0]]


def test_the_picture_script_runs_on_a_tiny_budget(tmp_path):
    data, png = tmp_path / "beside.json", tmp_path / "beside.png"
    script = [sys.executable, str(ROOT / "bench" / "beside_people.py")]
    measured = subprocess.run([*script, "measure", "--episodes", "2", "--followers", "copy", "bayes-people",
                               "bayes-limit", "--out", str(data)], capture_output=True, text=True, timeout=600)
    assert measured.returncode == 0, measured.stderr
    report = json.loads(data.read_text())
    assert set(report["cells"]) == {"astar", "slips_25", "late_8", "boltzmann_1", "wrong_5pct", "distracted",
                                    "wanderer"}
    assert len(report["cells"]["late_8"]["bayes-limit"]["net"]) == 2 and "accuracy" not in report["cells"]["astar"]["copy"]
    drawn = subprocess.run([*script, "draw", str(data), "--png", str(png)], capture_output=True, text=True, timeout=300)
    assert drawn.returncode == 0, drawn.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = [line for line in drawn.stdout.splitlines() if line.startswith("| `")]
    assert len(rows) == 6  # three followers beside the held-out people, three beside A*
    assert all("(the limit)" in row for row in rows if row.startswith("| `bayes-limit`"))
    limit_net = np.mean([np.mean(report["cells"][n]["bayes-limit"]["net"]) for n in report["held_out"]])
    assert f"{limit_net:+.2f}" in rows[2]

    # an arm of a sweep added to the kept report: its two seeds' followers, one episode each
    sweep = tmp_path / "runs" / "tiny_sweep"
    rows = ["trial,configuration,seed,finished"]
    for trial, seed, finished in (("t_b", 4, "True"), ("t_a", 3, "True"), ("t_c", 5, "False")):
        rows.append(f"{trial},partner=A*,{seed},{finished}")
        if finished == "True":
            (sweep / trial / "run" / "checkpoints").mkdir(parents=True)
            (sweep / trial / "run" / "checkpoints" / "latest.pt").write_bytes((ROOT / "checkpoints" / "follower.pt")
                                                                               .read_bytes())
    (sweep / "trials.csv").write_text("\n".join(rows) + "\n")
    added = subprocess.run([*script, "measure", "--episodes", "2", "--followers", "--arms", str(sweep),
                            "--add", str(data), "--out", str(data)], capture_output=True, text=True, timeout=600)
    assert added.returncode == 0, added.stderr
    merged = json.loads(data.read_text())
    arm = "arm:tiny_sweep/partner=A*"
    assert merged["followers"] == ["copy", "bayes-people", "bayes-limit", arm]
    assert merged["arms"][arm] == [str(sweep / t / "run" / "checkpoints" / "latest.pt") for t in ("t_a", "t_b")]
    assert merged["cells"]["late_8"]["copy"] == report["cells"]["late_8"]["copy"]  # the kept followers kept
    assert len(merged["cells"]["wanderer"][arm]["net"]) == 2 and "accuracy" in merged["cells"]["wanderer"][arm]
    drawn = subprocess.run([*script, "draw", str(data), "--png", str(png)], capture_output=True, text=True, timeout=300)
    assert drawn.returncode == 0, drawn.stderr
    assert "| `tiny_sweep: A*` |" in drawn.stdout
    other = subprocess.run([*script, "measure", "--episodes", "3", "--followers", "copy", "--add", str(data),
                            "--out", str(tmp_path / "other.json")], capture_output=True, text=True, timeout=600)
    assert other.returncode == 2 and "the kept report has episodes 2, this measure 3" in other.stderr


def test_an_arm_plays_its_episodes_in_blocks_one_a_seed():
    """An arm's seeds split a leader's episodes in consecutive blocks, each on the env seeds it would have alone."""
    sys.path.insert(0, str(ROOT / "bench"))
    from beside_people import cell, sweep_arms
    from colorgrid.policies.population import load_population

    leader = load_population("people#held_out")["late_8"]
    arm = cell(leader, ["bayes", "bayes-people"], 5, 3)
    first, second = cell(leader, "bayes", 3, 3), cell(leader, "bayes-people", 2, 6)
    for key in ("net", "wrong", "accuracy", "lags"):
        assert arm[key] == first[key] + second[key], key
    assert arm["after_switch"] == (np.asarray(first["after_switch"]) + second["after_switch"]).tolist()
    assert "accuracy" not in cell(leader, ["bayes", "copy"], 2, 0)  # a belief only where every seed has one
    with pytest.raises(ValueError, match="has no trials.csv"):
        sweep_arms(ROOT / "docs")


def test_without_the_limit_measured_no_follower_is_called_the_limit():
    sys.path.insert(0, str(ROOT / "bench"))
    from beside_people import table

    belief = {"accuracy": [0.5, 0.7], "log_loss": [0.3, 0.4], "lags": [1, 2]}
    report = {"followers": ["copy", "bayes"], "cells": {"x": {"copy": {"net": [1, 2], "wrong": [0, 1]},
                                                              "bayes": {"net": [3, 4], "wrong": [0, 0], **belief}}}}
    text = table(report, ["x"])
    assert "(the limit)" not in text and text.count("| - | - | - | - |") == 2
