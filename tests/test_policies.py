"""Scripted agents and the Bayesian follower's inference."""

import math
from collections import deque

import numpy as np
import pytest

from colorgrid import EnvConfig
from colorgrid.policies import AgentInput, BayesConfig, make_policy
from colorgrid.policies.bayes import move_likelihood, reward_likelihood, transition
from colorgrid.evaluate import switch_lags
from colorgrid.policies.grid import INF, decode, distance_field
from colorgrid.rollout import run_episodes
from tests.helpers import env_from_text

# 6x6 grid with two blocks of each color.
SIX = EnvConfig(height=6, width=6, block_density=0.17, switch_prob=0.0)


def leader_walk(env, steps, follower_action=None):
    """Drive the leader with the A* policy on a hand-built env; returns leader cells visited."""
    policy = make_policy("astar")
    policy.reset(env.config, 1, 0)
    obs = env._observations()
    cells, picked = [int(env.state.agent_cell[0, 0])], []
    for _ in range(steps):
        inp = AgentInput(obs["observation"], obs["goal_info"][:, 0], np.array([False]), np.zeros(1),
                         np.full((1, 2), -1), np.full((1, 2), -1))
        leader = int(policy.act(inp).actions[0])
        obs, _, _, _, info = env.step(np.array([[leader, follower_action if follower_action is not None else 0]]))
        cells.append(int(env.state.agent_cell[0, 0]))
        picked.append(int(info["picked_color"][0, 0]))
    return cells, picked


def test_astar_leader_takes_a_shortest_path():
    env = env_from_text(SIX, """
        L.....
        ......
        .....r
        ....r.
        g.....
        bgb.F.
    """, goal="red")
    _, picked = leader_walk(env, 7, follower_action=1)  # follower presses down at the bottom edge: stays
    assert picked[:7].index(0) == 6, "the nearest red block is 3 + 4 = 7 moves away (step index 6)"


def test_astar_leader_routes_around_wrong_blocks_when_it_can():
    env = env_from_text(SIX, """
        ..g...
        L.b...
        ..g..r
        ..b...
        .....r
        ....F.
    """, goal="red")
    _, picked = leader_walk(env, 12, follower_action=1)
    first_red = picked.index(0)
    assert all(c < 0 for c in picked[:first_red]), "no wrong block before reaching red"
    assert first_red == 7, "shortest clean path: down 3 to row 4, then right 5 (8 moves, step index 7)"


def test_astar_leader_without_any_path_still_acts_and_terminates():
    cfg = SIX.replace(hemispheres=True)
    # Both red blocks lie in the follower's half: the leader has no path to any goal block.
    env = env_from_text(cfg, """
        L..r..
        ......
        g.b...
        ...r..
        g.b...
        .....F
    """, goal="red")
    cells, picked = leader_walk(env, 40, follower_action=1)
    assert all(c % 6 < 3 for c in cells), "the leader stays in its half"
    assert len(set(cells)) > 1, "it keeps moving instead of freezing"


def bfs(targets: np.ndarray, passable: np.ndarray) -> np.ndarray:
    """One env's shortest 4-connected path lengths to the nearest passable target over passable cells, by a queue."""
    H, W = targets.shape
    dist = np.full((H, W), INF, dtype=np.int32)
    queue = deque(zip(*np.nonzero(targets & passable)))
    dist[targets & passable] = 0
    while queue:
        r, c = queue.popleft()
        for nr, nc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= nr < H and 0 <= nc < W and passable[nr, nc] and dist[nr, nc] == INF:
                dist[nr, nc] = dist[r, c] + 1
                queue.append((nr, nc))
    return dist


def test_distance_fields_are_shortest_paths_kept_up_to_the_farthest_start():
    """Each env's field is its own breadth-first search; with start cells, the distances beyond the farthest start's
    are ``INF`` (where every start is reached; else every field is whole)."""
    corridor = distance_field(np.array([[[False, False, True]]]), np.array([[[True, True, True]]]))
    assert corridor.tolist() == [[[2, 1, 0]]] and corridor.dtype == np.int32
    walled = distance_field(np.array([[[False, False, True]]]), np.array([[[True, False, True]]]))
    assert walled.tolist() == [[[INF, INF, 0]]]
    assert distance_field(np.zeros((0, 4, 5), bool), np.zeros((0, 4, 5), bool), np.zeros(0, int)).shape == (0, 4, 5)
    with pytest.raises(ValueError, match=r"a start cell in \[0, H\*W\) for each env"):
        distance_field(np.ones((1, 2, 2), bool), np.ones((1, 2, 2), bool), np.array([4]))
    rng = np.random.default_rng(7)
    for _ in range(200):
        B, H, W = (int(n) for n in rng.integers(1, [6, 14, 14]))
        targets = rng.random((B, H, W)) < rng.random() * 0.2
        passable = rng.random((B, H, W)) < 0.5 + rng.random() * 0.5
        whole = np.stack([bfs(t, p) for t, p in zip(targets, passable)])
        np.testing.assert_array_equal(distance_field(targets, passable), whole)
        np.testing.assert_array_equal(distance_field(np.asfortranarray(targets), passable.transpose(0, 2, 1).copy()
                                                     .transpose(0, 2, 1)), whole)  # not C-contiguous
        start = rng.integers(0, H * W, B)
        reached = whole.reshape(B, -1)[np.arange(B), start]
        kept = np.where(whole > reached.max(), INF, whole) if (reached < INF).all() else whole
        np.testing.assert_array_equal(distance_field(targets, passable, start_cell=start), kept)


def test_decoding_reads_each_cell_as_argmax_does_and_refuses_other_planes():
    """A cell's color is the first of its largest color planes (-1 where every one is 0), an agent's cell the first
    largest of its plane, for 0/1 planes and others alike."""
    planes = np.zeros((1, 5, 2, 2), dtype=np.float32)  # the default config's 3 colors and 2 agents
    planes[0, :3, 0, 1] = [1, 0, 0]
    planes[0, :3, 1, 0] = [0, 1, 1]  # a tie: the first color
    planes[0, :3, 1, 1] = [0, 2, 1]
    planes[0, 3, 1, 1] = planes[0, 4, 0, 1] = planes[0, 4, 1, 0] = 1  # the second agent's plane ties: its first cell
    for observation in (planes, planes.astype(np.uint8), planes[:, :, ::-1, :][:, :, ::-1, :]):
        block_color, agent_cell = decode(observation, EnvConfig())
        assert block_color.tolist() == [[[-1, 0], [1, 1]]] and agent_cell.tolist() == [[3, 1]]
        assert block_color.dtype == agent_cell.dtype == np.int64
    with pytest.raises(ValueError, match="observation has 6 planes; this config's have 5"):
        decode(np.zeros((1, 6, 2, 2), dtype=np.uint8), EnvConfig())


def test_copy_follower_waits_for_a_paying_pickup_then_copies_its_color():
    batch = run_episodes(EnvConfig(), make_policy("astar"), make_policy("copy"), 40, 300)
    T, B = batch.goal.shape
    matched = total = 0
    for e in range(B):
        paid = [t for t in range(T) if batch.picked_color[t, e, 0] >= 0 and batch.team_reward[t, e] > 0]
        assert paid, "the A* leader pays within an episode"
        follower_picks = [t for t in range(T) if batch.picked_color[t, e, 1] >= 0]
        assert all(t > paid[0] for t in follower_picks), "nothing collected before the first paying pickup"
        for t in follower_picks:
            copied = batch.picked_color[max(s for s in paid if s < t), e, 0]
            matched += batch.picked_color[t, e, 1] == copied
            total += 1
    assert total > 10 * B and matched / total > 0.95


def test_bayes_posterior_is_a_distribution_and_tracks_the_goal():
    batch = run_episodes(EnvConfig(), make_policy("astar"), make_policy("bayes"), 50, 1000)
    probs, goal = batch.goal_probs[1], batch.goal
    assert np.allclose(probs.sum(axis=2), 1.0, atol=1e-5) and (probs >= 0).all()
    assert (probs[0] == pytest.approx(1 / 3)), "uniform prior at the start"
    assert (probs.argmax(axis=2) == goal).mean() > 0.9
    lags = switch_lags(probs, goal)
    assert len(lags) > 50
    assert max(lags) <= 10, "after a switch the belief moves to the new goal within 10 leader moves"


def test_bayes_converges_on_a_stationary_goal():
    batch = run_episodes(EnvConfig(switch_prob=0.0), make_policy("astar"), make_policy("bayes"), 40, 7)
    final = batch.goal_probs[1][-1]
    assert (final.argmax(axis=1) == batch.goal[-1]).all()
    assert (final.max(axis=1) > 0.99).all()


def test_bayes_update_matches_a_hand_computed_example():
    beta, lapse = 1.0, 0.1
    d_before = np.array([[2.0, 3.0, 1.0]])
    d_after = np.array([[[1.0, 4.0, 2.0], [3.0, 2.0, 2.0], [3.0, 4.0, 0.0], [1.0, 3.0, 1.0]]])  # 4 actions
    observed = np.array([[True, False, False, False]])
    lik = move_likelihood(d_before, d_after, observed, beta, lapse)
    for k in range(3):
        weights = [math.exp(beta * (d_before[0, k] - d_after[0, a, k])) for a in range(4)]
        expected = (1 - lapse) * weights[0] / sum(weights) + lapse * 1 / 4
        assert lik[0, k] == pytest.approx(expected)
    cfg = EnvConfig()
    rl = reward_likelihood(np.array([[1, -1]]), np.array([1.0]), cfg, 1.0, 1, noise=1e-3)
    assert rl.tolist() == [[1e-3, 1.0, 1e-3]]
    rl = reward_likelihood(np.array([[1, 2]]), np.array([0.0]), cfg, 1.0, 1, noise=1e-3)
    assert rl.tolist() == [[1e-3, 1.0, 1.0]], "+1 - 1 = 0 is explained by goal green or goal blue"
    posterior = np.array([[1 / 3, 1 / 3, 1 / 3]]) * lik * rl
    posterior /= posterior.sum()
    after = transition(posterior, 0.03)
    assert after[0, 1] == pytest.approx(0.97 * posterior[0, 1] + 0.03 * (1 - posterior[0, 1]) / 2)
    assert after.sum() == pytest.approx(1.0)


def test_bayes_config_is_validated():
    with pytest.raises(ValueError, match=r"BayesConfig.lapse must be in \[0, 1\]"):
        BayesConfig(lapse=2.0)
    with pytest.raises(ValueError, match=r"BayesConfig.collect_threshold must be in \[0, 1\]"):
        BayesConfig(collect_threshold=-0.1)


def test_make_policy_rejects_unknown_names():
    with pytest.raises(ValueError, match=r"unknown policy 'nope'; choose one of \['astar'"):
        make_policy("nope")


def test_astar_refuses_to_play_without_the_goal():
    with pytest.raises(ValueError, match="the A\\* policy needs the goal"):
        run_episodes(EnvConfig(), make_policy("astar"), make_policy("astar"), 2, 0)


def test_acting_on_subsets_of_rows_matches_the_whole_batch():
    """The play server serves many games from one policy by passing ``rows``; beliefs must not mix."""
    from colorgrid import BatchEnv
    from colorgrid.config import FOLLOWER, LEADER
    from colorgrid.step_inputs import StepInputs

    cfg = EnvConfig()
    env = BatchEnv(cfg, num_envs=4, seed=21)
    obs, _ = env.reset()
    whole, split = make_policy("bayes"), make_policy("bayes")
    whole.reset(cfg, 4, 1)
    split.reset(cfg, 4, 1)
    leader = make_policy("astar")
    leader.reset(cfg, 4, 0)
    last = StepInputs.begin(cfg, 4)
    for _ in range(40):
        inp = last.agent_input(obs, FOLLOWER, 1.0, env.state.goal.copy())
        full = whole.act(inp)
        parts = np.zeros((4, 3), dtype=np.float32)
        for rows in ([2, 0], [3, 1]):
            parts[rows] = split.act(inp.select(rows), rows=np.array(rows)).goal_probs
        assert np.allclose(full.goal_probs, parts, atol=1e-6)
        lead = leader.act(last.agent_input(obs, LEADER, 1.0, None)).actions
        actions = np.stack([lead, full.actions], axis=1)
        obs, _, _, _, info = env.step(actions)
        last.record(actions, info)


def test_parameters_split_only_at_commas_outside_brackets():
    from colorgrid.policies import read_params

    assert read_params("steps=[1,2],base=(x.pt:temperature=0.5,greedy=true),slip=0.1", "n") == {
        "steps": [1, 2], "base": "x.pt:temperature=0.5,greedy=true", "slip": 0.1}
    assert read_params("slip=0.1,notice_delay=3", "n") == {"slip": 0.1, "notice_delay": 3}
    with pytest.raises(ValueError, match=r"unbalanced brackets in 'base=\(x\)\)'"):
        read_params("base=(x))", "n")
    assert make_policy("person:base=(astar),slip=0.1", "leader").describe()["params"]["slip"] == 0.1
