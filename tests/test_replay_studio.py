"""What-if branches of replays and followers rescored on recorded leaders' moves."""

import json
import subprocess
import sys

import pytest

from colorgrid.replay import load, save, verify
from colorgrid.replay.branch import branch, rescore
from tests.conftest import ROOT

PARENT = ROOT / "replays" / "default" / "astar+bayes_seed2026.replay.json"


@pytest.mark.parametrize("step", [0, 1, 50, 128])
def test_a_branch_verifies_and_shares_exactly_the_parents_first_steps(step):
    parent = load(PARENT)
    child = branch(parent, step, "copy", parent_name=PARENT.name)
    assert verify(child).ok and child.num_steps == parent.num_steps
    assert child.state_hashes[: step + 1] == parent.state_hashes[: step + 1]
    assert child.actions[:step] == parent.actions[:step]
    assert [a[0] for a in child.actions] == [a[0] for a in parent.actions]  # the leader replays its moves
    assert child.meta["branch"] == {"step": step, "follower": "copy", "leader": "recorded", "follower_seed": parent.seed}
    assert child.meta["branch_of"]["file"] == PARENT.name and child.agents["follower"]["policy"] == "copy"
    if step < 128:
        assert child.actions[step:] != parent.actions[step:]  # copy does not play like bayes


def test_the_same_follower_and_seed_from_step_zero_reproduces_its_own_game(tmp_path):
    from colorgrid.evaluate import evaluate

    evaluate(__import__("colorgrid").EnvConfig(horizon=40), "astar", "bayes", 1, 5, record_dir=tmp_path)
    parent = load(next(tmp_path.glob("*.replay.json")))
    child = branch(parent, 0, "bayes", seed=5)  # run_episodes seeds the policies with the evaluation's seed
    assert child.actions == parent.actions and child.state_hashes == parent.state_hashes


def test_a_branch_of_a_human_game_keeps_its_key_log_up_to_the_branch(tmp_path):
    parent = load(PARENT)
    parent.source = "play"
    parent.agents = {**parent.agents, "leader": {"policy": "human"}}
    parent.key_events = [{"seq": t, "key": "ArrowUp", "action": 0, "t_client": 1.0, "t_server": 2.0,
                          "applied_step": t, "status": "applied"} for t in range(parent.num_steps)]
    parent.key_events.append({"seq": 999, "key": "q", "t_client": 1.0, "t_server": 2.0, "applied_step": None,
                              "status": "ignored"})
    save(parent, tmp_path / "human.replay.json")
    child = branch(load(tmp_path / "human.replay.json"), 30, "bayes")
    assert verify(child).ok and child.source == "play" and child.agents["leader"] == {"policy": "human"}
    assert [e["applied_step"] for e in child.key_events] == list(range(30)) + [None]


def test_branch_with_a_leader_policy_and_clear_errors(tmp_path):
    parent = load(PARENT)
    child = branch(parent, 20, "bayes", leader="person:slip=0.2")
    assert verify(child).ok and child.actions[:20] == parent.actions[:20]
    assert child.agents["leader"]["policy"] == "person"
    with pytest.raises(ValueError, match=r"--step must be in \[0, 128\]"):
        branch(parent, 129, "copy")


def test_rescore_pairs_followers_on_the_same_leader_moves(tmp_path):
    files = sorted((ROOT / "replays" / "default").glob("*.replay.json"))[:3]
    report = rescore(files, ["copy", "bayes"])
    per_game = report["per_game"]
    assert len(per_game["copy"]) == 3
    for f in ("copy", "bayes"):
        expected = [branch(load(p), 0, f).final() for p in files]
        assert per_game[f] == [e["follower_goal_pickups"] - e["follower_wrong_pickups"] for e in expected]
    diffs = [b - c for b, c in zip(per_game["bayes"], per_game["copy"])]
    assert report["paired_difference"]["bayes"]["mean"] == pytest.approx(sum(diffs) / 3)
    out = tmp_path / "rescore.json"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "replay", "rescore", str(ROOT / "replays" / "default"),
                           "--follower", "copy", "bayes", "--json", str(out)], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert "bayes - copy:" in done.stdout and "open-loop" in done.stdout
    assert len(json.loads(out.read_text())["games"]) == 6
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "replay", "branch", str(PARENT), "--step", "10",
                           "--follower", "copy", "--out", str(tmp_path)], capture_output=True, text=True, timeout=300,
                          cwd=ROOT)
    assert done.returncode == 0 and "the first 10 the parent's; ok" in done.stdout, done.stderr
    branched = list(tmp_path.glob("*--branch10-copy.replay.json"))
    assert len(branched) == 1 and verify(load(branched[0])).ok
