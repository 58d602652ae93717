"""Leaders that stand in for people, populations, the people-robust Bayesian update, and the population matrix."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from colorgrid import BatchEnv, EnvConfig
from colorgrid.config import FOLLOWER, LEADER
from colorgrid.policies import PersonLeader, PersonStyle, make_policy
from colorgrid.policies.bayes import goal_transition, leader_transition, move_likelihood
from colorgrid.rollout import run_episodes
from colorgrid.step_inputs import StepInputs
from tests.conftest import ROOT


def drive(leader, config, num_envs=16, steps=None, seed=3, shadow=None):
    """Play ``leader`` (beside an idle follower) and yield each step's input and action; ``shadow`` acts on the
    same inputs alongside (its actions are yielded too, never played)."""
    env = BatchEnv(config, num_envs=num_envs, seed=seed, autoreset=False)
    obs, _ = env.reset()
    follower = make_policy("idle")
    for p, i in ((leader, LEADER), (follower, FOLLOWER), *(((shadow, LEADER),) if shadow else ())):
        p.reset(config, num_envs, i, seed=seed)
    last = StepInputs.begin(config, num_envs)
    for _ in range(steps or config.horizon):
        inp = last.agent_input(obs, LEADER, env.penalty_coef, env.state.goal.copy())
        lead = leader.act(inp).actions
        other = shadow.act(inp).actions if shadow else None
        actions = np.stack([lead, follower.act(last.agent_input(obs, FOLLOWER, env.penalty_coef, None)).actions], 1)
        yield inp, lead, other, env
        obs, _, _, _, info = env.step(actions)
        last.record(actions, info)


@pytest.mark.parametrize("delay", [0, 1, 4])
def test_a_late_leader_pursues_the_old_goal_for_exactly_k_steps_after_a_switch(delay):
    config = EnvConfig(switch_prob=0.05, horizon=200)
    lags = notice_lags(PersonLeader(PersonStyle(notice_delay=delay)), config, longest=delay)
    assert len(lags) > 20 and set(lags) == {delay}, lags


def notice_lags(leader, config: EnvConfig, longest: int, pursuing=lambda leader: leader.target) -> list[int]:
    """Steps from each switch until the leader pursues the new goal, over switches it had settled before and
    whose goal then held for ``longest + 1`` steps. ``pursuing(leader)``: the color each env's leader pursued at
    the step it just took (its ``target``, unless told)."""
    goals, pursued = [], []
    for inp, _, _, _ in drive(leader, config):
        goals.append(inp.goal_info.argmax(axis=1))
        pursued.append(np.array(pursuing(leader)))
    goals, pursued = np.array(goals), np.array(pursued)
    lags = []
    for e in range(goals.shape[1]):
        for t in np.nonzero(goals[1:, e] != goals[:-1, e])[0] + 1:
            stable = goals[t:t + longest + 1, e]
            settled = pursued[t - 1, e] == goals[t - 1, e]  # it had noticed the goal before this switch
            if settled and len(stable) == longest + 1 and (stable == goals[t, e]).all():
                lags.append(int(np.argmax(pursued[t:, e] == goals[t, e])))
    return lags


def test_a_leader_with_a_delay_range_notices_each_switch_after_a_delay_drawn_from_it():
    config = EnvConfig(switch_prob=0.05, horizon=200)
    lags = notice_lags(PersonLeader(PersonStyle(notice_delay=1, notice_delay_max=4)), config, longest=4)
    counts = np.bincount(lags, minlength=5)
    assert counts[0] == 0 and counts[1:].min() >= 5 and len(lags) > 40, counts  # every delay 1..4, none other


def test_a_fixed_delay_is_described_and_resumed_as_before_delays_could_vary():
    config = EnvConfig()
    assert "notice_delay_max" not in PersonLeader(PersonStyle(notice_delay=3)).describe()["params"]
    leader = PersonLeader(PersonStyle(notice_delay=3))
    leader.reset(config, 4, LEADER, seed=1)
    old = {k: v for k, v in leader.state_dict().items() if k != "delay"}  # a state saved before the field
    leader.delay[:] = 0
    leader.load_state_dict(old)
    assert (leader.delay == 3).all()


def test_the_varied_population_adds_one_training_member_and_keeps_the_held_out_part():
    from colorgrid.policies.population import load_population

    base, varied = load_population("people#training"), load_population("people_varied#training")
    assert varied == {**base, "late_0to4": "person:notice_delay=0,notice_delay_max=4"}
    assert load_population("people_varied#held_out") == load_population("people#held_out")
    with pytest.raises(ValueError, match="notice_delay_max must be"):
        PersonStyle(notice_delay=3, notice_delay_max=2)


def test_slips_happen_at_their_rate_within_a_binomial_bound():
    """A slip is a uniform move, so it differs from the A* leader's move on the same input 3/4 of the time."""
    slip, config = 0.2, EnvConfig(horizon=128)
    differs = [(lead != astar) for _, lead, astar, _ in drive(PersonLeader(PersonStyle(slip=slip)), config,
                                                              num_envs=32, shadow=make_policy("astar"))]
    rate, n, p = float(np.mean(differs)), np.size(differs), slip * 3 / 4
    assert abs(rate - p) < 4 * math.sqrt(p * (1 - p) / n), (rate, p, n)


def test_wrong_pickups_happen_when_scripted_and_not_otherwise():
    config = EnvConfig(horizon=128)
    tempted = run_episodes(config, make_policy("person:wrong_pickup=1.0"), make_policy("idle"), 8, 0)
    plain = run_episodes(config, make_policy("person"), make_policy("idle"), 8, 0)
    assert tempted.wrong_pickup[:, :, LEADER].sum(axis=0).min() >= 5
    assert plain.wrong_pickup[:, :, LEADER].sum() <= 1  # A*: only when boxed in


def test_a_person_with_every_departure_off_is_the_astar_leader():
    config = EnvConfig(horizon=64)
    a = run_episodes(config, make_policy("person"), make_policy("bayes"), 6, 1)
    b = run_episodes(config, make_policy("astar"), make_policy("bayes"), 6, 1)
    assert np.array_equal(a.actions, b.actions)


def test_specs_and_populations_give_clear_errors():
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['speed'\] of 'person'"):
        make_policy("person:speed=2")
    with pytest.raises(ValueError, match="PersonStyle.slip must be a probability in"):
        make_policy("person:slip=2")
    with pytest.raises(ValueError, match="population part 'test' is not one of"):
        make_policy("population:people#test")
    population = make_policy("population:people#held_out", role="leader")
    assert set(population.names).isdisjoint(make_policy("population:people#training", role="leader").names)


def test_population_play_gives_each_env_a_member_per_episode():
    config = EnvConfig(horizon=16)
    population = make_policy("population:people#held_out", role="leader")
    env = BatchEnv(config, num_envs=64, seed=0)
    obs, _ = env.reset()
    population.reset(config, 64, LEADER, seed=0)
    last = StepInputs.begin(config, 64)
    drawn = []
    for _ in range(3 * config.horizon):  # three episodes per env (autoreset)
        population.act(last.agent_input(obs, LEADER, 1.0, env.state.goal.copy()))
        drawn.append(population.member.copy())
        follower = np.zeros(64, dtype=np.int64)
        obs, _, _, truncs, info = env.step(np.stack([np.zeros(64, dtype=np.int64), follower], 1))
        last.record(np.stack([np.zeros(64, dtype=np.int64), follower], 1), info, truncs[:, 0])
    drawn = np.array(drawn)
    per_episode = drawn[:: config.horizon]  # [3, 64]
    assert (drawn[1:config.horizon] == drawn[0]).all()  # fixed within an episode
    assert len(np.unique(per_episode)) == len(population.names)  # every member plays
    assert (per_episode[0] != per_episode[1]).any()  # redrawn at episode starts


def test_people_robust_update_by_hand():
    """Two colors; the leader pursued the goal (red) when it slipped toward green."""
    beta, lapse, q, d, s = 1.0, 0.2, 0.5, 0.1, 0.05
    # distances to [red, green] before the move (2, 2); the four moves lead to (3,1) (the slip), (1,3), (2,2), (2,2)
    before = np.array([[2.0, 2.0]])
    after = np.array([[[3.0, 1.0], [1.0, 3.0], [2.0, 2.0], [2.0, 2.0]]])
    observed = np.array([[True, False, False, False]])
    z = math.exp(-1) + math.exp(1) + 2
    lik = np.array([0.8 * math.exp(-1) / z + 0.2 / 4, 0.8 * math.exp(1) / z + 0.2 / 4])  # pursuing red, green
    assert np.allclose(move_likelihood(before, after, observed, beta, lapse), lik)
    prior = np.array([[[0.9, 0.0], [0.0, 0.1]]])  # [goal, pursued]: red and pursuing red, 0.9
    post = prior * lik[None, None, :]
    post /= post.sum()
    switched = goal_transition(post, s)  # the goal switches with s (to the other color: C - 1 = 1)
    expected_switch = (1 - s) * post + s * post[:, ::-1, :]
    assert np.allclose(switched, expected_switch)
    joint = leader_transition(switched, q, d)
    g = switched[0]
    expected = np.array([[g[0, 0] * (1 - d) + g[0, 1] * q, g[0, 1] * (1 - q) + g[0, 0] * d],
                         [g[1, 0] * (1 - q) + g[1, 1] * d, g[1, 1] * (1 - d) + g[1, 0] * q]])
    assert np.allclose(joint[0], expected) and np.isclose(joint.sum(), 1.0)
    # the slip moved belief toward green, but less than if the leader always pursued the goal
    plain = prior.sum(axis=2)[0] * lik
    plain /= plain.sum()
    assert joint[0].sum(axis=1)[0] > plain[0] * (1 - s) + plain[1] * s - 1e-12


def test_the_people_model_with_its_extras_off_is_the_bayesian_follower():
    config = EnvConfig(horizon=64)
    a = run_episodes(config, make_policy("person:slip=0.1"), make_policy("bayes"), 6, 2)
    b = run_episodes(config, make_policy("person:slip=0.1"), make_policy("bayes-people:rationality=2.0,lapse=0.1,"
                                                                           "notice_rate=1.0,distraction=0.0"), 6, 2)
    assert np.array_equal(a.actions, b.actions) and np.allclose(a.goal_probs[FOLLOWER], b.goal_probs[FOLLOWER])


def test_the_population_matrix_json(tmp_path):
    out = tmp_path / "matrix.json"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "eval", "--leaders", "population:people#held_out",
                           "--compare", "copy", "bayes", "--episodes", "4", "--set", "horizon=32", "--json", str(out)],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    leaders = list(report["leaders"])
    assert report["followers"] == ["copy", "bayes"] and len(leaders) == 6
    for name in leaders:
        for follower in ("copy", "bayes"):
            m = report["cells"][name][follower]
            assert {"net_pickups", "wrong_pickups", "team_reward", "belief_accuracy", "steps_to_catch_a_switch"} <= set(m)
            assert set(m["net_pickups"]) == {"mean", "ci95"}
        assert set(report["paired_difference"]["bayes"][name]) == {"mean", "ci95"}
        assert report["cells"][name]["copy"]["belief_accuracy"] is None  # copy has no belief
    diff = report["paired_difference"]["bayes"][leaders[0]]["mean"]
    cells = report["cells"][leaders[0]]
    assert diff == pytest.approx(cells["bayes"]["net_pickups"]["mean"] - cells["copy"]["net_pickups"]["mean"])
    assert "paired difference in follower net pickups against copy" in done.stdout


def test_a_matrix_worker_computes_on_its_share_of_the_cpus():
    """Each pool worker's torch gets the threads its initializer shares out (``OMP_NUM_THREADS``, read when a cell
    imports torch), not a thread per core in every worker."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    import torch

    from colorgrid_apps.matrix import share_cpus

    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn"), initializer=share_cpus,
                             initargs=(1,)) as pool:
        assert [pool.submit(torch.get_num_threads).result() for _ in range(2)] == [1, 1]


def test_the_matrix_is_the_same_in_one_process_or_several():
    """In this process (torch at its own threads) or in two workers (one torch thread each), with a trained
    follower among the scripted ones: the same cells to the bit."""
    from colorgrid_apps.matrix import evaluate_matrix

    leaders = {"slips": "person:slip=0.2", "late": "person:notice_delay=5"}
    config = EnvConfig(horizon=32)
    one = evaluate_matrix(config, leaders, ["copy", "bayes", "ippo-people"], 4, 7, workers=1)
    two = evaluate_matrix(config, leaders, ["copy", "bayes", "ippo-people"], 4, 7, workers=2)
    assert one["cells"] == two["cells"] and one["paired_difference"] == two["paired_difference"]
