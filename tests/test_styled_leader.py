"""A person's departures around a trained leader (``person:base=ippo-leader,...``, ``colorgrid.policies.styled``):
the base's own actions with every departure off, the goal it is shown, slips, hesitation, wrong pickups, the
refusals, the command line, populations and a resumed state."""

import copy
import io
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from colorgrid import EnvConfig
from colorgrid.config import LEADER
from colorgrid.policies import Policy, PolicyOutput, StyledLeader, make_policy, policy_card, policy_teams
from colorgrid.policies.people import PersonStyle
from colorgrid.policies.population import load_population
from colorgrid.rollout import run_episodes
from tests.conftest import ROOT
from tests.test_people import drive, notice_lags


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """A batch of a few games through a small network: one torch thread, which beside other work on the machine
    is many times faster than two."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


class Shown(Policy):
    """A leader that acts as ``inner`` does and keeps the goal it is shown at each step (``shown[-1]``: ``[B]``)."""

    name = "shown"

    def __init__(self, inner: Policy):
        self.inner = inner

    def reset(self, config, num_envs, agent_index, seed=0):
        super().reset(config, num_envs, agent_index, seed)
        self.inner.reset(config, num_envs, agent_index, seed)
        self.shown = []

    def act(self, inp, rows=None) -> PolicyOutput:
        self.shown.append(inp.goal_info.argmax(axis=1))
        return self.inner.act(inp, rows)


def styled(spec: str) -> StyledLeader:
    """``make_policy(spec)`` with its base wrapped in ``Shown``."""
    leader = make_policy(spec, role="leader")
    assert isinstance(leader, StyledLeader)
    leader.base = Shown(leader.base)
    return leader


def test_with_every_departure_off_it_takes_the_base_leaders_own_actions():
    config = EnvConfig(horizon=64)
    a = run_episodes(config, make_policy("person:base=ippo-leader", role="leader"), make_policy("bayes"), 16, 5)
    b = run_episodes(config, make_policy("ippo-leader", role="leader"), make_policy("bayes"), 16, 5)
    assert np.array_equal(a.actions, b.actions)


def test_a_default_base_is_the_astar_person_described_as_before():
    plain, named = make_policy("person:slip=0.1"), make_policy("person:base=astar,slip=0.1")
    assert type(plain) is type(named) and plain.describe() == named.describe()
    assert "base" not in plain.describe()["params"]


def test_it_is_described_by_its_base_and_its_style_and_plays_its_bases_teams():
    spec = "person:base=ippo-leader,slip=0.1,notice_delay=3"
    described = make_policy(spec, role="leader").describe()
    assert described["base"] == make_policy("ippo-leader", role="leader").describe()
    assert described["params"]["base"] == "ippo-leader" and described["params"]["notice_delay"] == 3
    assert policy_teams(spec) == policy_teams("ippo-leader") == ("1:1",)
    assert policy_teams("person:slip=0.1") is None
    card, base = policy_card(spec).lead, policy_card("ippo-leader").lead
    assert card.label == "Person-like leader" and card.description.startswith(base.label) and "A*" not in card.description
    assert policy_card("person:base=runs/x/leader.pt").lead.description.startswith("runs/x/leader.pt, with the slips")
    assert policy_card("person:slip=0.1") == policy_card("person:base=astar,slip=0.1") == policy_card("person")


def test_the_play_server_keeps_a_person_around_a_network_warm_as_its_base():
    """Only a policy that is scripted all the way down is cheap to build; a person around a trained leader loads
    its network, so the server warms it and times its calls as it does the base's."""
    from server.followers import is_scripted

    assert is_scripted("person:slip=0.1") and is_scripted("person:base=astar,slip=0.1") and is_scripted("copy")
    assert not is_scripted("person:base=ippo-leader,slip=0.1") and not is_scripted("ippo-leader")
    assert not is_scripted("person:base=runs/x/leader.pt,slip=0.1") and not is_scripted("population:people")


@pytest.mark.parametrize("delay", [0, 3])
def test_the_base_is_shown_the_old_goal_for_exactly_k_steps_after_a_switch(delay):
    config = EnvConfig(switch_prob=0.05, horizon=200)
    lags = notice_lags(styled(f"person:base=ippo-leader,notice_delay={delay}"), config, longest=delay,
                       pursuing=lambda leader: leader.base.shown[-1])
    assert len(lags) > 20 and set(lags) == {delay}, lags


def test_a_slip_of_one_makes_every_move_uniformly_random():
    config = EnvConfig(horizon=64)
    moves = np.concatenate([lead for _, lead, _, _ in drive(styled("person:base=ippo-leader,slip=1"), config)])
    counts = np.bincount(moves, minlength=5)
    expected = len(moves) / 4
    chi2 = float(((counts[:4] - expected) ** 2 / expected).sum())
    assert counts[4] == 0 and chi2 < 16.27, counts  # 3 degrees of freedom, p = 0.001


def test_a_hesitating_leader_repeats_its_last_move_at_its_rate_and_otherwise_moves_as_its_base():
    """The base, shadowed by a second ippo-leader on the same inputs and seed, draws the same moves."""
    hesitate, config = 0.3, EnvConfig(horizon=64)
    made, based, last = [], [], None
    for inp, lead, base, _ in drive(make_policy(f"person:base=ippo-leader,hesitate={hesitate}", role="leader"), config,
                                    shadow=make_policy("ippo-leader", role="leader")):
        if last is not None:
            assert ((lead == base) | (lead == last)).all()  # its base's move, or the last one again
            made.append(lead[base != last] == last[base != last])
        last = lead
    made = np.concatenate(made)
    rate, n = float(made.mean()), len(made)
    assert abs(rate - hesitate) < 4 * math.sqrt(hesitate * (1 - hesitate) / n), (rate, n)


def test_a_wrong_pickup_draw_shows_a_wrong_color_until_a_block_is_collected():
    config = EnvConfig(horizon=128)
    leader = styled("person:base=ippo-leader,wrong_pickup=0.05")
    steps = [(inp.goal_info.argmax(axis=1), inp.prev_picked_color[:, LEADER] >= 0)
             for inp, _, _, _ in drive(leader, config, num_envs=16)]
    goals, picked = (np.array(column) for column in zip(*steps))  # [T, B] each: the goal, a block collected
    shown = np.array(leader.base.shown)
    wrong = shown != goals
    assert wrong.mean() > 0.1  # it sets off after wrong colors
    held = wrong[:-1] & ~picked[1:]  # a wrong color shown, and no block collected before the next step
    assert (shown[1:][held] == shown[:-1][held]).all()  # the same wrong color, until a block is collected
    ended = wrong[:-1] & picked[1:]
    assert ended.sum() > 10 and (~wrong[1:][ended]).mean() > 0.8  # then the goal again (unless drawn anew)


def test_rationality_with_another_base_and_a_follower_as_base_are_refused_in_one_line():
    with pytest.raises(ValueError, match=r"PersonStyle.rationality must be unset with base 'ippo-leader' \(a "
                                         r"Boltzmann choice over A\* distances: base astar only\), got 1.0$"):
        make_policy("person:base=ippo-leader,rationality=1.0")
    with pytest.raises(ValueError, match=r"'person:base=bayes,slip=0.1': PersonStyle.base must be astar, a leader "
                                         r"policy's name .* or a checkpoint path ending in .pt, got 'bayes' "
                                         r"\(not a leader policy\)$"):
        make_policy("person:base=bayes,slip=0.1")
    with pytest.raises(ValueError, match=r"PersonStyle.base must be .*, not a person leader itself, got "
                                         r"'person:slip=0.1'$"):
        make_policy("person:base=person:slip=0.1")
    with pytest.raises(ValueError, match=r"got 'population:people' \(a population; give each member its own base"):
        make_policy("person:base=population:people")
    with pytest.raises(ValueError, match=r"base 'checkpoints/follower.pt': .* holds no trained leader"):
        make_policy("person:base=checkpoints/follower.pt")


def test_eval_runs_with_a_styled_trained_leader():
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "eval", "--leader",
                           "person:base=ippo-leader,slip=0.1", "--follower", "bayes", "--episodes", "2",
                           "--set", "horizon=32"], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert "follower net pickups" in done.stdout


def test_a_population_member_may_be_a_styled_trained_leader(tmp_path):
    path = tmp_path / "trained_people.json"
    members = {"late_ippo": f"person:base={ROOT / 'checkpoints' / 'leader.pt'},notice_delay=3", "astar": "astar"}
    path.write_text(json.dumps({"training": members, "held_out": {}}))
    assert load_population(str(path)) == members
    population = make_policy(str(path), role="leader")
    assert isinstance(population.members["late_ippo"], StyledLeader)
    run_episodes(EnvConfig(horizon=32), population, make_policy("bayes"), 8, 0)
    assert set(population.member) == {0, 1}  # each member led some games


def test_a_restored_state_continues_exactly_with_the_bases_memory_and_generator():
    """Around an LSTM leader (untrained: its memory still changes its moves), through the trainer's checkpoint
    format: a fresh policy given the saved state takes the same actions on the same inputs."""
    import torch

    from train.agent_config import NetConfig
    from train.checkpoint import to_tensors
    from train.nets import ActorCritic
    from train.policy import NetPolicy

    config = EnvConfig(switch_prob=0.05, horizon=60)
    model = ActorCritic(NetConfig(lstm=True), config, LEADER)
    style = PersonStyle(base="lstm-leader", slip=0.2, notice_delay=1, notice_delay_max=4, wrong_pickup=0.05,
                        hesitate=0.1, detour=0.05)

    def fresh():
        leader = StyledLeader(NetPolicy(model, name="lstm-leader"), style)
        leader.reset(config, 8, LEADER, seed=4)
        return leader

    leader = fresh()
    inputs, actions = [], []
    for step, (inp, lead, _, _) in enumerate(drive(leader, config, num_envs=8, seed=4)):
        if step == 29:  # after its 30th step, as a resumable checkpoint keeps a partner
            buffer = io.BytesIO()
            torch.save(to_tensors(leader.state_dict()), buffer)
        if step >= 30:
            inputs.append(copy.deepcopy(inp))  # the step's buffers are reused for the next step's input
            actions.append(lead)
    resumed = fresh()
    resumed.load_state_dict(torch.load(io.BytesIO(buffer.getvalue()), weights_only=True))
    assert all(np.array_equal(resumed.act(inp).actions, lead) for inp, lead in zip(inputs, actions))
    restarted = fresh()  # without the state: other moves (the check above is not vacuous)
    assert not all(np.array_equal(restarted.act(inp).actions, lead) for inp, lead in zip(inputs, actions))
