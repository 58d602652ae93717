"""Behaviour cloning: a leader network learned from recorded games (``colorgrid train-bc``).

Top to bottom: find the ``*.replay.json`` files, keep the actions replays, re-simulate each
one (seed + actions, ``colorgrid.replay.replay_states``) to recover what the leader saw
before every step (the observation planes, its goal information and the previous step's
inputs, built exactly as ``NetPolicy`` builds them when it plays), split the *episodes*
into training and held-out sets, train the leader's ``ActorCritic`` by cross-entropy on the
recorded leader actions (its auxiliary head on the true goal; the value head is unused),
and save an exported-style checkpoint that loads wherever a policy name is accepted.

The network's shapes depend on the grid, the colors and whether ``stay`` exists, so the
episodes of one run must agree on ``height``, ``width``, ``num_colors`` and ``allow_stay``
(a real-time game's leader may ``stay``: such replays train a 5-action network).
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch.nn import functional as F

from colorgrid import configkit
from colorgrid.config import AGENTS, LEADER, EnvConfig
from colorgrid.configkit import check_choice, check_int, check_number, fail
from colorgrid.env import ACTION_NAMES, BatchEnv
from colorgrid.replay import SUFFIX, Replay, ReplayError, load, replay_states, verify
from colorgrid.step_inputs import StepInputs
from train.checkpoint import agent_entry, save_checkpoint
from train.config import DEVICES, NetConfig
from train.inputs import step_tensors
from train.nets import ActorCritic
from train.placement import device_name, pick_device

SHAPE_FIELDS = ("height", "width", "num_colors", "allow_stay")
"""The ``EnvConfig`` fields a network's input and output shapes depend on: one run's episodes must agree."""
_INPUTS = ("obs", "me", "goal", "extras", "starts")


@dataclass(frozen=True)
class BCConfig:
    """One behaviour-cloning run (``--set KEY=VALUE`` overrides any field, ``net.X`` the network's)."""

    epochs: int = 15
    """Passes over the training episodes."""
    seed: int = 0
    """Seeds the episode split, the network's initial weights and the minibatch order."""
    holdout: float = 0.2
    """Fraction of the episodes (not steps) held out to measure accuracy (0 <= holdout < 1; 0: none)."""
    lr: float = 2e-3
    """Adam learning rate."""
    batch_size: int = 64
    """Steps per gradient step; recurrent networks take whole episodes, as many as hold about this many steps."""
    aux_coef: float = 0.2
    """Weight of the auxiliary head's cross-entropy on the true goal (0: the head is left untrained)."""
    net: NetConfig = field(default_factory=lambda: NetConfig(goal_fusion="planes"))
    """The leader's network (default: the shipped leader's, goal given as input planes)."""
    device: str = "auto"
    threads: int = 1
    """Torch CPU threads during the run (0: torch's default, every core). The network is small and its batches
    are too: one thread is usually fastest, and on a busy machine several are many times slower."""

    def __post_init__(self):
        check_int(self, "epochs", 1)
        check_int(self, "seed", 0)
        check_int(self, "batch_size", 1)
        check_int(self, "threads", 0)
        check_number(self, "holdout", "a fraction with 0 <= holdout < 1", lambda v: 0 <= v < 1)
        check_number(self, "lr", "a positive number", lambda v: v > 0)
        check_number(self, "aux_coef", "a number >= 0", lambda v: v >= 0)
        check_choice(self, "device", DEVICES, f"choose one of {list(DEVICES)}")
        if self.net.leader_progress:
            fail(self, "net.leader_progress", "it is a follower's input (how the leader's moves read); a cloned "
                 "leader sees the goal: leave it false", True)

    def to_dict(self) -> dict:
        return configkit.to_dict(self)


def bc_config(changes: dict, overrides: list[str]) -> BCConfig:
    """A ``BCConfig`` from plain ``changes`` (``{"epochs": 5, "net": {"hidden": 64}}``), then ``KEY=VALUE``
    overrides."""
    # on top of the defaults, so that changing one network field keeps the others (goal_fusion="planes")
    return configkit.resolve(BCConfig, BCConfig().to_dict(), changes, overrides=overrides,
                             example="net.lstm=true or lr=3e-4")


# ------------------------------------------------------------------ finding and reading recordings
def replay_files(folders: list[str | Path]) -> list[Path]:
    """Every ``*.replay.json`` under ``folders`` (recursively), each once, sorted."""
    found: set[Path] = set()
    for folder in map(Path, folders):
        if not folder.is_dir():
            raise ValueError(f"{folder} is not a folder of recordings" if folder.exists()
                             else f"recordings folder {folder} does not exist")
        found.update(p.resolve() for p in folder.rglob(f"*{SUFFIX}") if p.is_file())
    if not found:
        raise ValueError(f"no {SUFFIX} files in {', '.join(map(str, folders))}")
    return sorted(found)


@dataclass
class Episode:
    """One recorded episode as its leader saw it: ``T`` steps, the inputs of ``train.inputs.step_tensors``."""

    path: Path
    config: EnvConfig
    leader: str  # the recorded leader's policy name ("human", "astar", a checkpoint's, ...)
    obs: np.ndarray  # [T, P, H, W] uint8 observation planes before each step
    me: np.ndarray  # [T, 2] int64 the leader's cell (row, column)
    goal: np.ndarray  # [T, C] float32 the leader's goal information
    extras: np.ndarray  # [T, E] float32 the previous step's reward, actions and collected colors
    starts: np.ndarray  # [T] bool, true at t = 0
    actions: np.ndarray  # [T] int64 the leader's recorded actions
    true_goal: np.ndarray  # [T] int64 the goal when each action was chosen

    @property
    def num_steps(self) -> int:
        return len(self.actions)


def leader_episode(replay: Replay, path: Path) -> Episode:
    """Re-simulate an actions replay and collect, for each step, the leader's input and its action.

    Raises ``ReplayError`` when the episode cannot be simulated or the re-simulation differs
    from the recorded state hashes (a replay of other rules).
    """
    config = replay.config
    states = replay_states(replay, path)
    if replay.state_hashes is not None:
        check = verify(replay, path, states)
        if not check.ok:
            raise ReplayError(path, f"re-simulation does not reproduce it: {check.message}")
    env = BatchEnv(config, num_envs=1, autoreset=False)
    last = StepInputs.begin(config, 1)
    steps = []
    for t, action in enumerate(replay.actions):
        obs = env.load_state(states[t])
        inp = last.agent_input(obs, LEADER, replay.penalty_coef, states[t].goal.copy())
        steps.append({k: v[0, 0].numpy() for k, v in step_tensors(inp, config, LEADER, "cpu").items()})
        info = {"block_reward": np.array([replay.block_reward[t]]), "team_reward": np.array([replay.team_reward[t]]),
                "picked_color": np.array([replay.picked_color[t]])}
        last.record(np.array([action]), info)
    arrays = {k: np.stack([s[k] for s in steps]) for k in _INPUTS}
    return Episode(path=path, config=config, leader=str(replay.agents.get(AGENTS[LEADER], {}).get("policy", "?")),
                   actions=np.array([a[LEADER] for a in replay.actions], dtype=np.int64),
                   true_goal=np.array(replay.goal, dtype=np.int64), **arrays)


def read_recordings(folders: list[str | Path], warn: Callable[[str], None]) -> list[Episode]:
    """The leader's view of every usable actions replay under ``folders``; files that do not load are skipped
    with one warning line. Refuses (``ValueError``, one line) when nothing usable is left."""
    files = replay_files(folders)
    episodes, bad, frames, branches, teams = [], [], 0, 0, 0
    for path in files:
        try:
            replay = load(path)
            if replay.kind != "actions":
                frames += 1
                continue
            if "branch_of" in replay.meta:  # what-if branches: after the branch step the leader's moves are
                branches += 1               # open-loop copies, not play
                continue
            if not replay.config.one_to_one:  # a room's game: the cloned leader is the 1:1 team's
                teams += 1
                continue
            episodes.append(leader_episode(replay, path))
        except ReplayError as err:
            bad.append(err)
    if bad:
        warn(f"warning: skipped {len(bad)} of {len(files)} replay files that do not load (first: {bad[0]})")
    if branches:
        warn(f"skipped {branches} what-if branches (meta.branch_of): their leader moves are not play")
    if teams:
        warn(f"skipped {teams} games of other teams than one leader and one follower (behaviour cloning learns "
             f"the 1:1 leader)")
    if not episodes:
        if teams:
            raise ValueError(f"none of the {len(files)} replays in {', '.join(map(str, folders))} is a 1:1 game "
                             f"({teams} games of other teams); behaviour cloning learns the 1:1 leader")
        if frames:
            raise ValueError(f"none of the {len(files)} replays in {', '.join(map(str, folders))} holds actions "
                             f"({frames} frames replays: their agents' actions are not recorded)")
        raise ValueError(f"none of the {len(files)} replay files in {', '.join(map(str, folders))} could be read")
    if frames:
        warn(f"warning: left out {frames} frames replays (no actions recorded)")
    return episodes


def shape_key(config: EnvConfig) -> tuple:
    return tuple(getattr(config, name) for name in SHAPE_FIELDS)


def common_config(episodes: list[Episode]) -> EnvConfig:
    """The config the episodes share (the most common one), or one line saying how they do not fit together."""
    groups = Counter(shape_key(e.config) for e in episodes)
    if len(groups) > 1:
        kinds = "; ".join(f"{h}x{w}, {c} colors, {'with' if stay else 'no'} stay: {n} episodes"
                          for (h, w, c, stay), n in groups.most_common())
        raise ValueError(f"the recordings mix configs that one network cannot serve ({', '.join(SHAPE_FIELDS)} "
                         f"differ): {kinds}; train on one kind at a time (one folder each)")
    return Counter(e.config for e in episodes).most_common(1)[0][0]


def split_episodes(num_episodes: int, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Episode indices for training and held out: ``round(holdout * N)`` (at least 1 when ``holdout > 0``) held out."""
    order = np.random.default_rng(seed).permutation(num_episodes)
    held = 0 if holdout == 0 else max(1, round(holdout * num_episodes))
    if held >= num_episodes:
        raise ValueError(f"--holdout {holdout} leaves no training episodes out of {num_episodes}; record more "
                         f"games or use --holdout 0")
    return np.sort(order[held:]), np.sort(order[:held])


# ------------------------------------------------------------------ the data as tensors
class Steps:
    """The steps of several episodes, concatenated (``S`` in all), and batches cut from them."""

    def __init__(self, episodes: list[Episode]):
        self.lengths = np.array([e.num_steps for e in episodes])
        self.offsets = np.concatenate([[0], np.cumsum(self.lengths)])
        cat = lambda name: torch.from_numpy(np.concatenate([getattr(e, name) for e in episodes]))  # noqa: E731
        self.inputs = {k: cat(k) for k in _INPUTS}  # obs [S, P, H, W] uint8, me [S, 2], goal [S, C], ...
        self.actions, self.true_goal = cat("actions"), cat("true_goal")  # [S] int64 each

    @property
    def num_steps(self) -> int:
        return int(self.offsets[-1])

    def batch(self, index: np.ndarray, device) -> dict[str, torch.Tensor]:
        """The steps ``index [T, B]`` as ``[T, B, ...]`` tensors on ``device``."""
        flat = torch.from_numpy(index.reshape(-1))
        return {k: v[flat].reshape(*index.shape, *v.shape[1:]).to(device)
                for k, v in {**self.inputs, "actions": self.actions, "true_goal": self.true_goal}.items()}

    def episode_index(self, episodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Episodes (local indices) as sequences: ``index [T, B]`` padded by repeating each one's last step, and
        ``mask [T, B]`` (true on real steps). ``T`` is the longest episode's length."""
        lengths = self.lengths[episodes]
        t = np.arange(lengths.max())[:, None]
        index = self.offsets[episodes][None, :] + np.minimum(t, lengths[None, :] - 1)
        return index, t < lengths[None, :]


def bc_loss(logits: torch.Tensor, goal_logits: torch.Tensor, actions: torch.Tensor, true_goal: torch.Tensor,
            mask: torch.Tensor, aux_coef: float) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Cross-entropy on the recorded actions plus ``aux_coef`` times the goal head's, over the real steps.

    logits ``[T, B, A]``, goal_logits ``[T, B, C]``, actions and true_goal ``[T, B]`` int64, mask ``[T, B]`` bool.
    """
    policy_loss = F.cross_entropy(logits[mask], actions[mask])
    aux_loss = F.cross_entropy(goal_logits[mask], true_goal[mask])
    correct = (logits[mask].argmax(dim=1) == actions[mask]).float().mean()
    return policy_loss + aux_coef * aux_loss, {"policy_loss": policy_loss, "aux_loss": aux_loss, "accuracy": correct}


def run_model(model: ActorCritic, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Action and goal logits, ``[T, B, A]`` and ``[T, B, C]``, for a batch of ``Steps.batch``."""
    view = model.prepare(batch["obs"], batch["me"])
    state = model.initial_state(batch["goal"].shape[1], batch["goal"].device)
    logits, _, goal_logits, _ = model(view, batch["goal"], batch["extras"], batch["starts"], state)
    return logits, goal_logits


@torch.inference_mode()
def accuracy(model: ActorCritic, steps: Steps, device, episodes_per_batch: int = 16) -> float:
    """Fraction of the steps where the network's most likely action is the recorded one (whole episodes, in order)."""
    correct = 0
    for first in range(0, len(steps.lengths), episodes_per_batch):
        index, mask = steps.episode_index(np.arange(first, min(first + episodes_per_batch, len(steps.lengths))))
        batch = steps.batch(index, device)
        logits, _ = run_model(model, batch)
        hits = (logits.argmax(dim=2) == batch["actions"]) & torch.from_numpy(mask).to(device)
        correct += int(hits.sum())
    return correct / steps.num_steps


def fit(model: ActorCritic, train: Steps, measured: Steps, config: BCConfig, device,
        report: Callable[[int, float, float], None]) -> tuple[list[float], list[float], int]:
    """``config.epochs`` passes of Adam over ``train`` (minibatches of steps, or of whole episodes for a recurrent
    network); after each, ``report(epoch, mean train loss, accuracy on measured)``. Returns the losses, the
    accuracies and the number of samples seen."""
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    generator = torch.Generator().manual_seed(config.seed)
    episodes_per_batch = max(1, round(config.batch_size / train.lengths.mean()))
    losses, accuracies, seen = [], [], 0
    for epoch in range(1, config.epochs + 1):
        if model.lstm is not None:
            order = torch.randperm(len(train.lengths), generator=generator).numpy()
            batches = [train.episode_index(order[i:i + episodes_per_batch])
                       for i in range(0, len(order), episodes_per_batch)]
        else:
            order = torch.randperm(train.num_steps, generator=generator).numpy()
            batches = [(part[None], np.ones((1, len(part)), dtype=bool))
                       for part in np.split(order, range(config.batch_size, len(order), config.batch_size))]
        total, count = 0.0, 0
        for index, mask in batches:
            batch = train.batch(index, device)
            logits, goal_logits = run_model(model, batch)
            loss, _ = bc_loss(logits, goal_logits, batch["actions"], batch["true_goal"],
                              torch.from_numpy(mask).to(device), config.aux_coef)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            n = int(mask.sum())
            total, count = total + float(loss.detach()) * n, count + n
        seen += count
        losses.append(total / count)
        accuracies.append(accuracy(model, measured, device))
        report(epoch, losses[-1], accuracies[-1])
    return losses, accuracies, seen


# ------------------------------------------------------------------ the run
@dataclass
class BCResult:
    """What a run measured and where it saved the leader."""

    path: Path
    episodes: dict  # {"train": n, "held_out": m}
    steps: dict  # {"train": n, "held_out": m}
    train_loss: list  # per epoch
    accuracy: list  # per epoch, on the held-out episodes (the training ones when none are held out)
    majority_action: int
    majority_accuracy: float  # always answering the training set's most common action, on the same steps
    chance: float  # 1 / num_actions

    @property
    def final_accuracy(self) -> float:
        return self.accuracy[-1]


def train_bc(folders: list[str | Path], out: str | Path, config: BCConfig | None = None,
             log: Callable[[str], None] = print,
             warn: Callable[[str], None] = lambda line: print(line, file=sys.stderr)) -> BCResult:
    """Learn a leader from the recordings under ``folders`` and save it to ``out`` (see the module docstring)."""
    config = config or BCConfig()
    start = time.perf_counter()
    episodes = read_recordings(folders, warn)
    env_config = common_config(episodes)
    if len({e.config for e in episodes}) > 1:
        log("note: the episodes differ in settings that do not change the network's shapes; the checkpoint "
            "records the most common config")
    train_ids, held_ids = split_episodes(len(episodes), config.holdout, config.seed)
    train = Steps([episodes[i] for i in train_ids])
    held = Steps([episodes[i] for i in held_ids]) if len(held_ids) else None
    measured, where = (held, "held-out") if held is not None else (train, "training")
    leaders = Counter(e.leader for e in episodes)
    log(f"{len(episodes)} episodes ({train.num_steps + (held.num_steps if held else 0)} leader steps; leaders: "
        + ", ".join(f"{name} x{n}" for name, n in leaders.most_common()) + f"): {len(train_ids)} to train, "
        f"{len(held_ids)} held out; {env_config.height}x{env_config.width}, {env_config.num_colors} colors, "
        f"{env_config.num_actions} actions")

    # Network, then the epochs ---------------------------------------------------------------------------
    device = pick_device(config.device)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = ActorCritic(config.net, env_config, LEADER).to(device)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads or threads)
    trained_on = device_name(device)
    try:
        losses, accuracies, seen = fit(model, train, measured, config, device,
                                       lambda epoch, loss, acc: log(f"epoch {epoch}/{config.epochs}: train loss "
                                                                    f"{loss:.4f}, {where} accuracy {acc:.1%}"))
    finally:
        torch.set_num_threads(threads)

    # Baselines and the checkpoint ----------------------------------------------------------------------
    majority = int(torch.bincount(train.actions, minlength=env_config.num_actions).argmax())
    majority_accuracy = float((measured.actions == majority).float().mean())
    chance = 1.0 / env_config.num_actions
    result = BCResult(Path(out), {"train": len(train_ids), "held_out": len(held_ids)},
                      {"train": train.num_steps, "held_out": held.num_steps if held else 0}, losses, accuracies,
                      majority, majority_accuracy, chance)
    log(f"{where} accuracy {accuracies[-1]:.1%} on {measured.num_steps} steps; majority action "
        f"({ACTION_NAMES[majority]}) {majority_accuracy:.1%}; chance {chance:.1%}")
    agents = {name: None for name in AGENTS}
    agents[AGENTS[LEADER]] = agent_entry(model.cpu(), None)
    run = {"method": "behaviour cloning", "bc": config.to_dict(), "recordings": [str(f) for f in folders],
           "leaders": dict(leaders), "episodes": result.episodes, "steps": result.steps,
           "accuracy": {"measured_on": where, "final": accuracies[-1], "majority_action": majority_accuracy,
                        "chance": chance}}
    save_checkpoint(out, {"config": run, "env_config": env_config.to_dict(), "step": seen, "iteration": config.epochs,
                          "wall_time_s": time.perf_counter() - start, "device": trained_on,
                          "agents": agents, "trainer_state": None})
    log(f"wrote {out}: the leader, for --leader {out} (or make_policy({str(out)!r}, role='leader'))")
    return result
