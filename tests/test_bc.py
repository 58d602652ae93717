"""Behaviour cloning (``train/bc.py``, ``colorgrid train-bc``): a leader learned from recorded A* games."""

import subprocess
import sys

import numpy as np
import pytest
import torch

from colorgrid import BatchEnv, EnvConfig
from colorgrid.config import LEADER
from colorgrid.policies import AStarLeader, make_policy
from colorgrid.replay import import_frames, load, save
from colorgrid.rollout import run_episodes
from colorgrid.evaluate import evaluate
from train.bc import BCConfig, bc_config, bc_loss, leader_episode, split_episodes, train_bc
from train.checkpoint import load_checkpoint
from train.inputs import step_tensors

CONFIG = EnvConfig(horizon=64)
FAST = BCConfig(epochs=8, batch_size=32, threads=1)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """30 episodes of the A* leader beside the Bayesian follower, as replays."""
    folder = tmp_path_factory.mktemp("recordings")
    evaluate(CONFIG, "astar", "bayes", 30, seed=0, record_dir=folder / "astar")
    return folder


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "colorgrid_apps", *args], capture_output=True, text=True, timeout=120)


def test_the_leader_learns_the_recorded_actions_and_the_result_plays(recordings, tmp_path):
    out = tmp_path / "leader_bc.pt"
    lines = []
    result = train_bc([recordings], out, FAST, log=lines.append)
    assert result.chance == 0.25 and result.episodes == {"train": 24, "held_out": 6}
    assert result.final_accuracy > 0.5, lines
    assert result.final_accuracy > result.majority_accuracy + 0.15, lines
    assert sum(line.startswith("epoch ") for line in lines) == FAST.epochs
    assert any("majority action" in line and "chance 25.0%" in line for line in lines)

    ckpt = load_checkpoint(out)
    assert ckpt["trainer_state"] is None and ckpt["agents"]["follower"] is None
    assert ckpt["iteration"] == FAST.epochs and ckpt["step"] == FAST.epochs * result.steps["train"]
    assert ckpt["config"]["method"] == "behaviour cloning" and ckpt["env_config"]["horizon"] == 64

    leader = make_policy(str(out), role="leader")
    batch = run_episodes(EnvConfig(horizon=32), leader, make_policy("bayes", role="follower"), 2, seed=5)
    assert batch.actions.shape == (32, 2, 2) and (batch.actions[..., LEADER] < 4).all()
    assert batch.goal_pickup[..., LEADER].sum() > batch.wrong_pickup[..., LEADER].sum()


class Recorder(AStarLeader):
    """The A* leader, keeping the network inputs of what it was shown at every step."""

    def act(self, inp, rows=None):
        self.seen.append({k: v[0, 0].numpy() for k, v in step_tensors(inp, self.config, LEADER, "cpu").items()})
        return super().act(inp, rows)


def test_the_re_simulated_inputs_are_the_ones_the_leader_saw(tmp_path):
    recorder = Recorder()
    recorder.seen = []
    config = EnvConfig(horizon=24, reward_mode="individual")
    [path] = evaluate(config, recorder, "bayes", 1, seed=3, record_dir=tmp_path)["replays"]
    episode = leader_episode(load(path), path)
    assert episode.num_steps == 24 and episode.starts.tolist() == [True] + [False] * 23
    for name in ("obs", "me", "goal", "extras", "starts"):
        np.testing.assert_array_equal(getattr(episode, name), np.stack([s[name] for s in recorder.seen]), name)


def test_the_split_is_by_episode_and_seeded():
    train, held = split_episodes(10, 0.2, seed=4)
    assert len(held) == 2 and sorted([*train, *held]) == list(range(10))
    assert np.array_equal(held, split_episodes(10, 0.2, seed=4)[1])
    assert len(split_episodes(10, 0.0, seed=4)[1]) == 0
    with pytest.raises(ValueError, match="no training episodes"):
        split_episodes(1, 0.5, seed=0)


def test_bc_loss_golden_values():
    logits = torch.tensor([[[0.0, 0.0], [2.0, 0.0]]])  # [T=1, B=2, A=2]
    goal_logits = torch.zeros(1, 2, 3)
    actions, goal = torch.tensor([[0, 1]]), torch.tensor([[0, 2]])
    loss, stats = bc_loss(logits, goal_logits, actions, goal, torch.tensor([[True, True]]), aux_coef=0.5)
    policy = (np.log(2) + (np.log(1 + np.exp(2)))) / 2  # -log softmax of the taken actions, averaged
    assert float(stats["policy_loss"]) == pytest.approx(policy, rel=1e-6)
    assert float(loss) == pytest.approx(policy + 0.5 * np.log(3), rel=1e-6)
    assert float(stats["accuracy"]) == 0.5
    masked, _ = bc_loss(logits, goal_logits, actions, goal, torch.tensor([[True, False]]), aux_coef=0.0)
    assert float(masked) == pytest.approx(np.log(2), rel=1e-6)


def test_changing_one_network_field_keeps_the_other_defaults():
    config = bc_config({"net": {"hidden": 32}}, ["net.lstm=true", "lr=1e-3"])
    assert config.net.hidden == 32 and config.net.lstm and config.net.goal_fusion == "planes" and config.lr == 1e-3


def test_the_command_trains_and_eval_plays_the_result(recordings, tmp_path):
    out = tmp_path / "leader_bc.pt"
    done = cli("train-bc", str(recordings), "--out", str(out), "--epochs", "1", "--seed", "1", "--holdout", "0.25",
               "--net-hidden", "32", "--set", "batch_size=128")
    assert done.returncode == 0, done.stderr
    assert "epoch 1/1: train loss" in done.stdout and "chance 25.0%" in done.stdout
    assert load_checkpoint(out)["agents"]["leader"]["net"]["hidden"] == 32
    done = cli("eval", "--leader", str(out), "--follower", "bayes", "--episodes", "2", "--set", "horizon=16")
    assert done.returncode == 0, done.stderr
    assert "leader net pickups" in done.stdout


def frames_replay(config: EnvConfig):
    env = BatchEnv(config, num_envs=1, seed=0)
    planes, goal_info = [], []
    for _ in range(3):
        obs = env.step(np.zeros((1, 2), dtype=np.int64))[0] if planes else env.reset()[0]
        planes.append(obs["observation"][0].copy())
        goal_info.append(obs["goal_info"][0].copy())
    return import_frames(config, np.stack(planes), np.stack(goal_info))


def test_unusable_recordings_are_refused_in_one_line(recordings, tmp_path):
    def refused(folders, match):
        with pytest.raises(ValueError, match=match) as err:
            train_bc(folders, tmp_path / "never.pt", FAST, log=lambda line: None, warn=warnings.append)
        assert "\n" not in str(err.value)

    warnings = []
    refused([tmp_path / "missing"], "does not exist")
    (tmp_path / "empty").mkdir()
    refused([tmp_path / "empty"], "no .replay.json files")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "a.replay.json").write_text("{}")
    refused([broken], "could be read")
    assert len(warnings) == 1 and warnings[0].startswith("warning: skipped 1 of 1 replay files")
    save(frames_replay(EnvConfig(horizon=8)), tmp_path / "frames" / "f.replay.json")
    refused([tmp_path / "frames"], "holds actions")
    evaluate(EnvConfig(horizon=16, allow_stay=True), "astar", "bayes", 2, seed=0, record_dir=tmp_path / "stay")
    refused([recordings, tmp_path / "stay"], r"mix configs .*no stay: 30 episodes.*with stay: 2 episodes")

    done = cli("train-bc", str(tmp_path / "missing"))
    assert done.returncode == 2 and done.stderr.strip().count("\n") == 0
    assert done.stderr.startswith("colorgrid train-bc: error: recordings folder")


def test_broken_files_are_skipped_with_one_warning(recordings, tmp_path):
    folder = tmp_path / "mixed"
    folder.mkdir()
    for path in sorted((recordings / "astar").glob("*.replay.json"))[:5]:
        (folder / path.name).write_bytes(path.read_bytes())
    (folder / "z.replay.json").write_text("not json")
    save(frames_replay(CONFIG), folder / "frames.replay.json")
    warnings = []
    result = train_bc([folder], tmp_path / "small.pt", BCConfig(epochs=1, threads=1), log=lambda line: None,
                      warn=warnings.append)
    assert result.episodes == {"train": 4, "held_out": 1}
    assert [w.split(" (")[0] for w in warnings] == ["warning: skipped 1 of 7 replay files that do not load",
                                                    "warning: left out 1 frames replays"]


def test_games_of_other_teams_are_left_out_with_a_warning(recordings, tmp_path):
    from tests.test_teams_replays import team_replay

    folder = tmp_path / "rooms"
    folder.mkdir()
    save(team_replay(2, 1), folder / "room.replay.json")
    with pytest.raises(ValueError, match=r"is a 1:1 game \(1 games of other teams\)") as err:
        train_bc([folder], tmp_path / "never.pt", BCConfig(epochs=1, threads=1), log=lambda line: None,
                 warn=lambda line: None)
    assert "\n" not in str(err.value)
    for path in sorted((recordings / "astar").glob("*.replay.json"))[:3]:
        (folder / path.name).write_bytes(path.read_bytes())
    warnings = []
    result = train_bc([folder], tmp_path / "small.pt", BCConfig(epochs=1, threads=1), log=lambda line: None,
                      warn=warnings.append)
    assert sum(result.episodes.values()) == 3
    assert [w.split(" (")[0] for w in warnings] == ["skipped 1 games of other teams than one leader and one follower"]
