"""A trained network's acting temperature: ``NAME:temperature=T`` on any shipped agent or checkpoint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from colorgrid.config import FOLLOWER, EnvConfig
from colorgrid.policies import make_policy, policy_teams
from colorgrid.rollout import run_episodes
from train.inputs import step_tensors

CHECKPOINT = str(Path(__file__).resolve().parents[1] / "checkpoints" / "follower.pt")
CONFIG = EnvConfig(horizon=24)


def play(follower: str, seed: int = 0):
    return run_episodes(CONFIG, make_policy("astar", "leader"), make_policy(follower, "follower"), 8, seed)


def test_temperature_zero_takes_the_most_likely_action_of_the_network():
    """Step by step, the greedy follower's action is the argmax of the network's own logits."""
    from colorgrid.env import BatchEnv
    from colorgrid.step_inputs import StepInputs

    policy = make_policy(f"{CHECKPOINT}:temperature=0", "follower")
    shadow = make_policy(CHECKPOINT, "follower")  # the same network, to read its logits alongside
    leader = make_policy("astar", "leader")
    env = BatchEnv(CONFIG, num_envs=4, seed=3)
    obs, _ = env.reset()
    last = StepInputs.begin(CONFIG, 4)
    for p, agent in ((policy, FOLLOWER), (shadow, FOLLOWER), (leader, 0)):
        p.reset(CONFIG, 4, agent, seed=agent + 1)
    for _ in range(20):
        mine = last.agent_input(obs, FOLLOWER, env.penalty_coef, env.state.goal.copy())
        x = step_tensors(mine, CONFIG, FOLLOWER, "cpu")
        with torch.inference_mode():
            view = shadow.model.prepare(x["obs"], x["me"])
            logits, _, _, shadow.state = shadow.model(view, x["goal"], x["extras"], x["starts"], shadow.state)
        actions = np.stack([leader.act(last.agent_input(obs, 0, env.penalty_coef, env.state.goal.copy())).actions,
                            policy.act(mine).actions], axis=1)
        assert (actions[:, 1] == logits[0].argmax(dim=1).numpy()).all()
        obs, _, _, _, info = env.step(actions)
        last.record(actions, info)


def test_a_greedy_follower_ignores_its_random_generator_and_a_sampling_one_does_not():
    """The same episodes with the follower's generator seeded differently: greedy actions are the same."""
    def actions(spec: str, follower_seed: int) -> np.ndarray:
        policy = make_policy(spec, "follower")
        reset = policy.reset
        policy.reset = lambda config, n, agent, seed=0: reset(config, n, agent, seed=follower_seed)
        return run_episodes(CONFIG, make_policy("astar", "leader"), policy, 8, 0).actions[:, :, FOLLOWER]

    assert (actions("ippo:temperature=0", 1) == actions("ippo:temperature=0", 2)).all()
    assert (actions("ippo", 1) != actions("ippo", 2)).any()


def test_temperature_one_is_the_default_and_acts_identically():
    default, explicit = play("ippo"), play("ippo:temperature=1")
    assert (default.actions == explicit.actions).all()
    assert "temperature" not in make_policy("ippo", "follower").describe()  # replays as before


def test_a_low_temperature_sharpens_sampling_towards_the_greedy_actions():
    """Over the same episodes, temperature 0.2 agrees with greedy on more steps than temperature 1 does."""
    greedy = play("ippo:temperature=0").actions[:, :, FOLLOWER]
    cold = play("ippo:temperature=0.2").actions[:, :, FOLLOWER]
    warm = play("ippo:temperature=1").actions[:, :, FOLLOWER]
    assert (cold == greedy).mean() > (warm == greedy).mean()


def test_the_temperature_is_recorded_in_the_policy_description():
    assert make_policy("ippo-people:temperature=0.5", "follower").describe()["temperature"] == 0.5
    assert make_policy(f"{CHECKPOINT}:temperature=0", "follower").describe()["temperature"] == 0.0


@pytest.mark.parametrize("spec, words", [
    ("ippo:temperature=-0.5", ["temperature=-0.5 is invalid", "0 (greedy) or a finite number >= 0.01"]),
    ("ippo:temperature=0.001", ["temperature=0.001 is invalid"]),  # logits / 0.001 would overflow float32
    ("ippo:temperature=true", ["temperature=True is invalid"]),
    ("ippo:temperature=hot", ["temperature='hot' is invalid"]),
    ("ippo:heat=1", ["unknown parameter(s) ['heat']", "allowed: ['temperature', 'min_belief']"]),
    (f"{CHECKPOINT}:heat=1", ["unknown parameter(s) ['heat']", "a checkpoint path ending in .pt"]),
    ("ippo:temperature", ["expected NAME:KEY=VALUE"]),
    ("ippo:temperature=[0.5", ["unbalanced brackets in 'temperature=[0.5'"]),
])
def test_a_bad_temperature_or_parameter_is_refused_in_one_line(spec, words):
    with pytest.raises(ValueError) as err:
        make_policy(spec, "follower")
    message = str(err.value)
    assert "\n" not in message and all(w in message for w in words), message


def test_an_exported_checkpoint_carries_how_it_acts_and_a_name_can_override_it(tmp_path):
    """``checkpoint export --temperature 0``: the file acts greedily wherever it is loaded without a temperature;
    ``:temperature=1`` still samples; ``checkpoint info`` shows it."""
    import json
    import subprocess
    import sys

    greedy_file = tmp_path / "greedy.pt"
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "checkpoint", "export", CHECKPOINT, "--agent",
                           "follower", "--temperature", "0", "--out", str(greedy_file)], cwd=root,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert make_policy(str(greedy_file), "follower").temperature == 0.0
    assert (play(str(greedy_file)).actions == play("ippo:temperature=0").actions).all()
    assert (play(f"{greedy_file}:temperature=1").actions == play("ippo").actions).all()
    info = subprocess.run([sys.executable, "-m", "colorgrid_apps", "checkpoint", "info", str(greedy_file)], cwd=root,
                          capture_output=True, text=True, timeout=120)
    assert json.loads(info.stdout)["temperature"] == {"follower": 0.0}
    bad = subprocess.run([sys.executable, "-m", "colorgrid_apps", "checkpoint", "export", CHECKPOINT, "--agent",
                          "follower", "--temperature", "-2", "--out", str(tmp_path / "bad.pt")], cwd=root,
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "temperature=-2.0 is invalid" in bad.stderr and len(bad.stderr.splitlines()) == 1
    assert not (tmp_path / "bad.pt").exists()


def test_a_checkpoint_with_acting_settings_plays_the_teams_its_file_plays():
    """``x.pt:temperature=0`` is ``x.pt`` acting greedily: offered in the team it was trained in, not in every team
    (as follower), and as leader where the plain file leads."""
    from colorgrid.enums import SeatFit
    from server.followers import leads, plays
    from server.protocol import Team

    team_file = str(Path(CHECKPOINT).with_name("follower_1L2F.pt"))
    leader_file = str(Path(CHECKPOINT).with_name("leader.pt"))
    PAIR_VIEW = SeatFit.PAIR_VIEW
    assert policy_teams(f"{team_file}:temperature=0") == policy_teams(team_file) == ("1:2",)
    assert policy_teams(f"{CHECKPOINT}:temperature=0,min_belief=0.5") == ("1:1",)
    assert [t for t in Team if plays(f"{team_file}:temperature=0", t)] == [Team.TWO_FOLLOWERS]
    assert [leads(f"{leader_file}:temperature=0", t) for t in Team] == [leads(leader_file, t) for t in Team] == [
        "direct", PAIR_VIEW, None]


# ------------------------------------------------------------------ min_belief
def test_unsure_moves_are_the_moves_onto_blocks_the_belief_doubts():
    """A hand-built board: the follower at (2, 2) with a block of color 0 above, color 1 below, color 2 to the
    left, nothing to the right (actions: up, down, left, right)."""
    from colorgrid.policies.grid import unsure_moves
    from colorgrid.env import move_table

    config = EnvConfig(height=5, width=5, block_density=0.2)
    obs = np.zeros((2, config.num_colors + config.num_agents, 5, 5), dtype=np.uint8)
    obs[:, 0, 1, 2] = obs[:, 1, 3, 2] = obs[:, 2, 2, 1] = 1
    obs[:, config.num_colors + 0, 0, 0] = 1  # the leader, far away
    obs[:, config.num_colors + FOLLOWER, 2, 2] = 1
    belief = np.array([[0.8, 0.15, 0.05], [0.5, 0.45, 0.05]], dtype=np.float32)
    moves = move_table(config)[FOLLOWER]
    unsure = unsure_moves(obs, belief, moves, config, FOLLOWER, 0.6)
    assert unsure[:, :4].tolist() == [[False, True, True, False], [True, True, True, False]]
    obs[:, 0, 2, 3] = 1  # boxed in by blocks: every move would be unsure, so none is taken out
    assert not unsure_moves(obs, belief, moves, config, FOLLOWER, 0.9).any()
    staying = EnvConfig(height=5, width=5, block_density=0.2, allow_stay=True)  # a network without stay, boxed in:
    four = move_table(staying)[FOLLOWER][:, :4]  # only its four moves count, or it could be left none
    assert not unsure_moves(obs, belief, four, staying, FOLLOWER, 0.9).any()


def test_min_belief_keeps_the_follower_off_blocks_it_is_unsure_of():
    """min_belief=1 (no belief is ever quite 1): it collects only where every move is onto a block; 0 leaves it."""
    free, strict = play("ippo"), play("ippo:min_belief=1")
    collected = lambda batch: int((batch.picked_color[:, :, FOLLOWER] >= 0).sum())  # noqa: E731
    assert collected(free) > 20 and collected(strict) <= 2
    assert (play("ippo:min_belief=0").actions == free.actions).all()
    staying = EnvConfig(horizon=24, allow_stay=True)  # the server's real-time mode: the env has stay, the net not
    batch = run_episodes(staying, make_policy("astar", "leader"), make_policy("ippo:min_belief=1", "follower"), 8, 0)
    assert int((batch.picked_color[:, :, FOLLOWER] >= 0).sum()) <= 2
    assert make_policy("ippo-cautious:min_belief=0.7", "follower").describe()["min_belief"] == 0.7
    assert "min_belief" not in make_policy("ippo", "follower").describe()


@pytest.mark.parametrize("value", ["-0.1", "1.5", "true", "high"])
def test_a_bad_min_belief_is_refused_in_one_line(value):
    with pytest.raises(ValueError) as err:
        make_policy(f"ippo:min_belief={value}", "follower")
    assert "min_belief=" in str(err.value) and "a number in [0, 1]" in str(err.value) and "\n" not in str(err.value)


def test_an_exported_checkpoint_carries_its_min_belief(tmp_path):
    import json
    import subprocess
    import sys

    careful = tmp_path / "careful.pt"
    root = Path(__file__).resolve().parents[1]
    export = [sys.executable, "-m", "colorgrid_apps", "checkpoint", "export", CHECKPOINT, "--agent", "follower"]
    done = subprocess.run(export + ["--min-belief", "0.8", "--out", str(careful)], cwd=root, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert (play(str(careful)).actions == play("ippo:min_belief=0.8").actions).all()
    assert (play(f"{careful}:min_belief=0").actions == play("ippo").actions).all()
    info = subprocess.run([sys.executable, "-m", "colorgrid_apps", "checkpoint", "info", str(careful)], cwd=root,
                          capture_output=True, text=True, timeout=120)
    assert json.loads(info.stdout)["min_belief"] == {"follower": 0.8}
    bad = subprocess.run(export + ["--min-belief", "2", "--out", str(tmp_path / "bad.pt")], cwd=root,
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--min-belief: min_belief=2.0 is invalid" in bad.stderr, bad.stderr
