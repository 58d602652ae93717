"""Scripted agents, the rollout and the evaluation command in teams of any shape."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from colorgrid import BatchEnv, EnvConfig
from colorgrid.policies import AgentInput, Policy, make_policy
from colorgrid.policies.bayes import move_likelihood
from colorgrid.policies.grid import decode
from colorgrid.rollout import run_episodes, run_team
from colorgrid.scenario import state_from_text
from colorgrid.step_inputs import StepInputs
from tests.conftest import ROOT

UP, DOWN, LEFT, RIGHT = range(4)
SIX = dict(height=6, width=6, block_density=0.17, switch_prob=0.0)  # two blocks of each color
RED, GREEN, BLUE = range(3)


def team_env(config: EnvConfig, text: str, goal="red") -> tuple[BatchEnv, dict]:
    env = BatchEnv(config, num_envs=1, seed=0)
    obs = env.load_state(state_from_text(config, text, goal=goal))
    return env, obs


def reset_all(config: EnvConfig, policies: list) -> None:
    for i, policy in enumerate(policies):
        policy.reset(config, 1, i)


# ------------------------------------------------------------ A* leaders share out the goal blocks
CLAIM_BOARD = """
    L1 . r . . .
    L2 . . . . .
    .  . . . . .
    .  . . . . .
    g  g b b . .
    .  . . . r F1
"""


def test_astar_leaders_in_a_2_1_team_go_for_different_blocks():
    config = EnvConfig(**SIX, num_leaders=2)
    env, obs = team_env(config, CLAIM_BOARD)
    leaders = [make_policy("astar"), make_policy("astar")]
    reset_all(config, leaders + [make_policy("idle")])
    last = StepInputs.begin(config, 1)
    block_color, agent_cell = decode(obs["observation"], config)
    claimed = leaders[1].claims(np.array([[True, False, False]]), block_color, agent_cell)
    assert np.argwhere(claimed[0]).tolist() == [[0, 2]], "leader_0 claims the red block two steps away"
    assert leaders[0].claims(np.array([[True, False, False]]), block_color, agent_cell) is None
    first = [int(p.act(last.agent_input(obs, i, 1.0, None)).actions[0]) for i, p in enumerate(leaders)]
    assert first == [RIGHT, DOWN], "leader_0 takes the near red block; leader_1 heads for the far one (8 moves)"

    # a lone A* leader at leader_1's cell would go for the near block (3 moves: right, then up-right)
    alone = EnvConfig(**SIX)
    lone_env, lone_obs = team_env(alone, CLAIM_BOARD.replace("L1", ".").replace("L2", "L").replace("F1", "F"))
    lone = make_policy("astar")
    lone.reset(alone, 1, 0)
    assert int(lone.act(StepInputs.begin(alone, 1).agent_input(lone_obs, 0, 1.0, None)).actions[0]) in (UP, RIGHT)

    picked, far = [], []
    for _ in range(8):
        actions = np.array([[int(p.act(last.agent_input(obs, i, 1.0, None)).actions[0]) for i, p in enumerate(leaders)]
                            + [DOWN]])  # the follower presses down at the bottom edge: it stays
        obs, _, _, _, info = env.step(actions)
        last.record(actions, info)
        picked.append(info["picked_color"][0].tolist())
        row, col = divmod(int(env.state.agent_cell[0, 1]), 6)
        far.append(abs(row - 5) + abs(col - 4))
    assert picked[1][0] == RED, "leader_0 collects the near red block at its second step"
    assert far[:4] == [7, 6, 5, 4], "leader_1 walks straight toward the far red block"
    collected = np.array(picked)[:, :2]
    assert set(collected[collected >= 0].tolist()) == {RED} and (collected == RED).any(axis=0).all(), \
        "both leaders collect red blocks within 8 steps, nothing else"


def test_a_leader_whose_goal_blocks_are_all_claimed_still_goes_for_the_nearest():
    config = EnvConfig(**SIX, num_leaders=3)
    env, obs = team_env(config, """
        L1 . r . . .
        L2 . . . . .
        L3 . . . . .
        .  . . . . .
        g  g b b . .
        .  . . . r F1
    """)
    leaders = [make_policy("astar") for _ in range(3)]
    reset_all(config, leaders + [make_policy("idle")])
    last = StepInputs.begin(config, 1)
    block_color, agent_cell = decode(obs["observation"], config)
    claimed = leaders[2].claims(np.array([[True, False, False]]), block_color, agent_cell)
    assert np.argwhere(claimed[0]).tolist() == [[0, 2], [5, 4]], "leader_0 and leader_1 claim one red block each"
    actions = [int(p.act(last.agent_input(obs, i, 1.0, None)).actions[0]) for i, p in enumerate(leaders)]
    assert actions[2] == RIGHT, "every red block is claimed: leader_2 heads for the nearest anyway (up is blocked)"


def test_a_person_with_every_departure_off_is_the_astar_leader_in_a_team_too():
    config = EnvConfig(num_leaders=2, horizon=48)
    people = run_team(config, [make_policy("person"), make_policy("person"), make_policy("idle")], 4, 2)
    astar = run_team(config, [make_policy("astar"), make_policy("astar"), make_policy("idle")], 4, 2)
    assert np.array_equal(people.actions, astar.actions)


# ------------------------------------------------------------ the copy follower
def copy_after(config: EnvConfig, text: str, steps: list[tuple[list[int], float]], agent: int) -> int:
    """The copy follower ``agent``'s target after seeing each ``(picked colors per agent, reward)``."""
    env, obs = team_env(config, text)
    follower = make_policy("copy")
    follower.reset(config, 1, agent)
    A = config.num_agents
    follower.act(AgentInput(obs["observation"], np.zeros((1, 3), np.float32), np.array([True]), np.zeros(1),
                            np.full((1, A), -1), np.full((1, A), -1)))
    for picked, reward in steps:
        follower.act(AgentInput(obs["observation"], np.zeros((1, 3), np.float32), np.array([False]),
                                np.array([reward], np.float32), np.array([picked]), np.zeros((1, A), np.int64)))
    return int(follower.target[0])


ONE_TWO = """
    L1 . r . . .
    .  . . . . .
    .  . . . . .
    F1 . . . . .
    g  g b b . .
    .  . . . r F2
"""


@pytest.mark.parametrize("steps, target", [
    ([([-1, GREEN, -1], 1.0)], GREEN),  # the second leader's pickup paid
    ([([RED, -1, -1], -1.0)], -1),  # it did not pay
    ([([RED, GREEN, -1], 0.0)], -1),  # +1 - 1: nothing paid
    ([([RED, GREEN, RED], 1.0)], RED),  # only "red is the goal" explains +1 (2 - 1); green would give -1
    ([([-1, GREEN, -1], 1.0), ([BLUE, -1, -1], 1.0)], BLUE),  # the last paying pickup counts
    ([([-1, GREEN, -1], 1.0), ([-1, -1, RED], 1.0)], GREEN),  # a follower's pickup is not copied
])
def test_the_copy_follower_adopts_a_paying_leaders_color_in_2_1(steps, target):
    assert copy_after(EnvConfig(**SIX, num_leaders=2), CLAIM_BOARD, steps, agent=2) == target


def test_the_copy_followers_of_a_1_2_team_both_copy_the_leader():
    config = EnvConfig(**SIX, num_followers=2)
    steps = [([BLUE, -1, -1], 1.0), ([-1, RED, -1], 1.0)]  # the leader's blue paid; follower_0's red is not copied
    assert [copy_after(config, ONE_TWO, steps, agent) for agent in config.followers] == [BLUE, BLUE]


@pytest.mark.parametrize("leaders, followers", [(2, 1), (1, 2)])
def test_copy_followers_collect_the_color_of_the_last_paying_leader_pickup(leaders, followers):
    config = EnvConfig(num_leaders=leaders, num_followers=followers, horizon=64)
    batch = run_team(config, [make_policy("astar") for _ in range(leaders)]
                     + [make_policy("copy") for _ in range(followers)], 12, 40)
    T, B = batch.goal.shape
    matched = total = 0
    for e in range(B):
        paying = {t: batch.picked_color[t, e, i] for t in range(T) for i in config.leaders
                  if batch.picked_color[t, e, i] >= 0 and batch.team_reward[t, e] > 0}
        for f in config.followers:
            for t in np.nonzero(batch.picked_color[:, e, f] >= 0)[0]:
                earlier = [s for s in paying if s < t]
                assert earlier, "nothing is collected before a leader's pickup paid"
                matched += batch.picked_color[t, e, f] == paying[max(earlier)]
                total += 1
    assert total > 5 * B * followers and matched / total > 0.9


# ------------------------------------------------------------ the Bayesian follower with two leaders
EVIDENCE_BOARD = """
    r  . . . . .
    .  . . . . .
    L1 . g . . .
    .  . . . . r
    L2 . g . b .
    .  . . . b F1
"""


def belief_after_one_step(config: EnvConfig, text: str, leader_actions: list[int], follower: str = "bayes"):
    """The follower's belief after watching the leaders take ``leader_actions`` (it stays, pressing down)."""
    env, obs = team_env(config, text, goal="red")
    policy = make_policy(follower)
    policy.reset(config, 1, config.num_leaders)
    last = StepInputs.begin(config, 1)
    first = policy.act(last.agent_input(obs, config.num_leaders, 1.0, None))
    assert np.allclose(first.goal_probs, 1 / 3)
    actions = np.array([leader_actions + [DOWN]])
    obs, _, _, _, info = env.step(actions)
    last.record(actions, info)
    return policy.act(last.agent_input(obs, config.num_leaders, 1.0, None)).goal_probs[0], info, policy


def test_two_leaders_moves_multiply_into_the_posterior_by_hand():
    """Both leaders step right, toward a green block; Manhattan distances to the nearest red, green and blue
    block before the move and after each of up, down, left (a wall: no move), right, worked out on the board."""
    config = EnvConfig(**SIX, num_leaders=2)
    belief, info, _ = belief_after_one_step(config, EVIDENCE_BOARD, [RIGHT, RIGHT])
    assert (info["picked_color"] < 0).all()
    leader_0 = ([2, 2, 6], [[1, 3, 7], [3, 3, 5], [2, 2, 6], [3, 1, 5]])  # from (2, 0) to (2, 1)
    leader_1 = ([4, 2, 4], [[3, 3, 5], [5, 3, 4], [4, 2, 4], [5, 1, 3]])  # from (4, 0) to (4, 1)
    beta, lapse = 2.0, 0.1

    def likelihood(before, after):
        out = []
        for k in range(3):
            weights = [math.exp(beta * (before[k] - after[a][k])) for a in range(4)]
            out.append((1 - lapse) * weights[RIGHT] / sum(weights) + lapse / 4)
        return np.array(out)

    lik_0, lik_1 = likelihood(*leader_0), likelihood(*leader_1)
    observed = np.array([[False, False, False, True]])
    assert np.allclose(move_likelihood(np.array([leader_0[0]], float), np.array([leader_0[1]], float), observed,
                                       beta, lapse), lik_0)
    both = lik_0 * lik_1 / (lik_0 * lik_1).sum()  # uniform prior, no switches (switch_prob = 0), no pickups
    assert belief == pytest.approx(both, abs=1e-6)
    one = lik_0 / lik_0.sum()
    entropy = [float(-(p * np.log(p)).sum()) for p in (belief, one)]
    assert belief.argmax() == GREEN and belief[GREEN] > one[GREEN] and entropy[0] < entropy[1], \
        "two leaders' evidence is sharper than one's"


@pytest.mark.parametrize("follower", ["bayes", "bayes-people"])
def test_one_leaders_wrong_pickup_is_evidence_against_its_color(follower):
    config = EnvConfig(**SIX, num_leaders=2)
    board = EVIDENCE_BOARD.replace("L2 . g . b .", ".  . g L2 b .")  # leader_1 beside a blue block
    belief, info, policy = belief_after_one_step(config, board, [RIGHT, RIGHT], follower)
    assert info["picked_color"][0].tolist() == [-1, BLUE, -1] and info["team_reward"][0] == -1.0
    assert belief[BLUE] < 0.01, "the team lost a point when leader_1 took blue: blue is not the goal"
    assert belief.sum() == pytest.approx(1.0, abs=1e-6)
    if follower == "bayes-people":  # one (goal, pursued) table per leader, the same goal marginal
        marginals = policy.joint[0].sum(axis=2)
        assert np.allclose(marginals[0], marginals[1]) and np.allclose(marginals[0], belief, atol=1e-6)


def test_a_saved_one_to_one_bayes_state_of_the_old_shape_still_loads():
    config = EnvConfig()
    policy = make_policy("bayes-people")
    policy.reset(config, 2, 1)
    state = policy.state_dict()
    state["joint"] = state["joint"][:, 0]  # [B, C, C], as saved before teams
    policy.load_state_dict(state)
    assert policy.joint.shape == (2, 1, 3, 3)


# ------------------------------------------------------------ the rollout
class Watcher(Policy):
    """Plays ``inner`` and keeps every agent's cell at every step, read from the observation."""

    name = "watcher"

    def __init__(self, inner: Policy):
        self.inner, self.cells = inner, []

    def reset(self, config, num_envs, agent_index, seed=0):
        super().reset(config, num_envs, agent_index, seed)
        self.inner.reset(config, num_envs, agent_index, seed)

    def act(self, inp, rows=None):
        self.cells.append(decode(inp.observation, self.config)[1])
        return self.inner.act(inp, rows)


@pytest.mark.parametrize("leaders, followers, follower", [(2, 1, "bayes"), (1, 2, "copy"), (2, 2, "oracle"),
                                                           (3, 3, "bayes-people")])
def test_run_team_astar_leaders_score_and_no_agents_overlap(leaders, followers, follower):
    config = EnvConfig(num_leaders=leaders, num_followers=followers, horizon=48)
    watcher = Watcher(make_policy(follower))
    policies = [make_policy("astar") for _ in range(leaders)] + [make_policy(follower) for _ in range(followers - 1)]
    batch = run_team(config, policies + [watcher], 6, 11)
    assert batch.actions.shape == (48, 6, leaders + followers) and len(batch.goal_probs) == leaders + followers
    assert (batch.team_reward.sum(axis=0) > 0).all()
    leader_goal = batch.goal_pickup[:, :, :leaders].sum(axis=0)
    assert (leader_goal > 0).all() and batch.wrong_pickup[:, :, :leaders].sum() <= 1
    cells = np.sort(np.stack(watcher.cells), axis=2)  # [T, B, A]
    assert (np.diff(cells, axis=2) > 0).all(), "no two agents ever share a cell"
    if follower.startswith("bayes"):
        probs = batch.goal_probs[leaders]
        assert np.allclose(probs.sum(axis=2), 1.0, atol=1e-5) and (probs.argmax(axis=2) == batch.goal).mean() > 0.6


def test_run_episodes_is_run_team_of_a_1_1_team():
    config = EnvConfig(horizon=48, switch_prob=0.05)
    for leader, follower in (("astar", "bayes-people"), ("person:slip=0.1", "copy")):
        a = run_episodes(config, make_policy(leader), make_policy(follower), 5, 3, record_hashes=True)
        b = run_team(config, [make_policy(leader), make_policy(follower)], 5, 3, record_hashes=True)
        for name in ("actions", "goal", "block_reward", "team_reward", "picked_color", "goal_switched",
                     "state_hashes"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert all((p is None and q is None) or np.array_equal(p, q) for p, q in zip(a.goal_probs, b.goal_probs))


def test_run_team_refuses_a_wrong_number_or_a_shared_policy():
    config = EnvConfig(num_leaders=2, horizon=8)
    with pytest.raises(ValueError, match=r"one policy per agent \['leader_0', 'leader_1', 'follower_0'\], got 2"):
        run_team(config, [make_policy("astar"), make_policy("idle")], 1, 0)
    leader = make_policy("astar")
    with pytest.raises(ValueError, match="a separate policy object for each agent"):
        run_team(config, [leader, leader, make_policy("idle")], 1, 0)
    with pytest.raises(ValueError, match="use run_team"):
        run_episodes(config, make_policy("astar"), make_policy("idle"), 1, 0)


# ------------------------------------------------------------ the evaluation command
def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "colorgrid_apps", *args], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)


def test_eval_of_a_team_reports_every_agent_and_every_role(tmp_path):
    out = tmp_path / "team.json"
    result = run_cli("eval", "--team", "2:2", "--compare", "copy", "bayes", "--agent", "leader_1=person:slip=0.1",
                     "--episodes", "3", "--set", "horizon=24", "--json", str(out))
    assert result.returncode == 0, result.stderr
    assert "astar/person:slip=0.1 + copy×2" in result.stdout and "leaders (2) net pickups" in result.stdout
    assert "follower_1 belief accuracy" in result.stdout and "colorgrid_teams_v0" in result.stdout
    reports = json.loads(out.read_text())["reports"]
    assert [r["policies"]["follower_0"]["policy"] for r in reports] == ["copy", "bayes"]
    for report in reports:
        assert report["env_id"] == "colorgrid_teams_v0"
        assert report["config"]["num_leaders"] == 2 and report["config"]["num_followers"] == 2
        assert list(report["agents"]) == ["leader_0", "leader_1", "follower_0", "follower_1"]
        assert report["policies"]["leader_1"]["policy"] == "person"
        assert {"block_reward", "goal_pickups", "wrong_pickups", "net_pickups"} <= set(report["agents"]["leader_0"])
        assert set(report["roles"]) == {"leader", "follower"}
        for role, names in (("leader", ["leader_0", "leader_1"]), ("follower", ["follower_0", "follower_1"])):
            entry = report["roles"][role]
            assert entry["agents"] == 2
            assert {"block_reward", "goal_pickups", "wrong_pickups", "net_pickups", "net_pickups_per_agent"} <= set(entry)
            total = sum(report["agents"][n]["net_pickups"]["mean"] for n in names)
            assert entry["net_pickups"]["mean"] == pytest.approx(total)
            assert entry["net_pickups_per_agent"]["mean"] == pytest.approx(total / 2)
    assert "belief" not in reports[0]["roles"]["follower"]
    assert set(reports[1]["roles"]["follower"]["belief"]) == {"agents", "accuracy", "log_loss"}


@pytest.mark.parametrize("args, words", [
    (["--team", "2x1"], ["argument --team", "LEADERS:FOLLOWERS", "'2x1'"]),
    (["--team", "9:1"], ["argument --team", "1..8"]),
    (["--team", "2:1", "--agent", "leader_7=astar"], ["no agent 'leader_7'", "'leader_0', 'leader_1', 'follower_0'"]),
    (["--team", "2:1", "--agent", "leader_1"], ["--agent expects NAME=POLICY"]),
    (["--team", "2:1", "--set", "num_leaders=3"], ["--team 2:1 disagrees with the config's team 3:1"]),
    (["--team", "2:1", "--leaders", "population:people"], ["--leaders pairs one leader", "1:1"]),
])
def test_eval_rejects_a_bad_team_in_one_line(args, words):
    result = run_cli("eval", *args, "--episodes", "1", "--set", "horizon=8")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    [line] = result.stderr.strip().splitlines()
    assert line.startswith("colorgrid eval: error: ")
    for word in words:
        assert word in line, (word, line)


def test_an_astar_agent_in_a_followers_seat_respects_no_leaders_claim():
    cfg = EnvConfig(height=5, width=5, block_density=0.24, switch_prob=0.0, asymmetric=False)
    state = state_from_text(cfg, """
        L.r.g
        .....
        ..F..
        .....
        g.rbb
    """, goal="red")
    env = BatchEnv(cfg, num_envs=1)
    obs = env.load_state(state)
    follower = make_policy("astar")
    follower.reset(cfg, 1, 1)
    inp = StepInputs.begin(cfg, 1).agent_input(obs, 1, 1.0, state.goal.copy())
    # both red blocks are two steps away; the leader heads for the top one, and the follower may too (up)
    assert follower.act(inp).actions.tolist() == [0]
