"""IPPO for ColorGrid, top to bottom: build agents, then loop rollout -> update -> log -> evaluate -> save.

Each learning agent has its own actor-critic and optimizer (independent PPO); a partner
that does not learn is any ``Policy``: scripted (A*, idle, ...) or a frozen checkpoint.
Everything that decides what happens next (env state, recurrent states, last-step inputs,
RNGs) is saved in checkpoints, so a resumed run continues exactly as if never stopped.
"""

from __future__ import annotations

import dataclasses
import json
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

from colorgrid.config import AGENTS, EnvConfig
from colorgrid.env import BatchEnv
from colorgrid.policies import make_policy
from colorgrid.replay import describe_agent
from colorgrid.rollout import run_episodes
from colorgrid.state import EnvState
from colorgrid.step_inputs import StepInputs
from colorgrid_apps.evaluate import evaluate, record_batch
from train.checkpoint import (agent_entry, build_model, load_checkpoint, load_weights, save_checkpoint,
                              to_arrays, to_tensors)
from train.config import TrainConfig
from train.inputs import step_tensors
from train.learner import Learner
from train.memory import keep_freed_memory
from train.metrics import MetricsLog
from train.nets import ActorCritic
from train.policy import NetPolicy, check_compatible


TRAINER_STATE_FORMAT = 2
"""Version of the resumable trainer state in checkpoints (1 was a pickle, which ``--resume`` no longer reads)."""


def pick_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("device='cuda' but no CUDA device is available; use 'auto' or 'cpu'")
    return torch.device(name)


def device_name(device: torch.device) -> str:
    """What trained: the GPU's name, or the CPU's with its thread count."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    from colorgrid_apps.machine import cpu_name

    return f"{cpu_name()} ({torch.get_num_threads()} torch threads)"


def update_learner(learner: Learner, inputs: dict, threads: int | None = None) -> dict:
    """One learner's bootstrap value and PPO update, both at ``threads`` torch threads (None: as set).

    The thread count is set on the calling thread itself: OpenMP keeps it per thread, so a
    worker thread must not inherit whatever its pool was created with.
    """
    if threads is not None:
        torch.set_num_threads(threads)
    return learner.update(learner.value(inputs))


class Trainer:
    def __init__(self, config: TrainConfig, run_dir: str | Path, progress: bool = True, tensorboard: bool = True):
        self.config, self.run_dir, self.progress = config, Path(run_dir), progress
        if config.threads:
            torch.set_num_threads(config.threads)
        torch.manual_seed(config.seed)
        self.device = pick_device(config.device)
        if config.keep_freed_memory and self.device.type == "cpu" and not keep_freed_memory():
            warnings.warn("keep_freed_memory=true needs glibc's malloc (Linux); memory is used as usual", stacklevel=2)
        self.env = BatchEnv(config.env, num_envs=config.ppo.num_envs, seed=config.seed)
        self.learners: dict[int, Learner] = {}
        self.partners: dict[int, object] = {}
        for i, agent in enumerate(config.agents):
            if agent.learns:
                self.learners[i] = self._make_learner(i)
            else:
                self.partners[i] = make_policy(agent.policy, role=AGENTS[i])
                self.partners[i].reset(config.env, config.ppo.num_envs, i, seed=config.seed)
        self.step, self.iteration = 0, 0
        self.wall_time = 0.0  # wall-clock seconds of training so far, across resumes
        self._tick = time.perf_counter()
        self._begin_episodes()
        self.tensorboard = tensorboard
        self.log: MetricsLog | None = None
        self._pool: ThreadPoolExecutor | None = None

    def _make_learner(self, i: int) -> Learner:
        cfg, agent = self.config, self.config.agents[i]
        if agent.init is None:
            model = ActorCritic(agent.net, cfg.env, i)
        else:
            ckpt = load_checkpoint(agent.init)
            entry = ckpt["agents"].get(AGENTS[i])
            if entry is None:
                raise ValueError(f"{AGENTS[i]}.init={agent.init!r} holds no trained {AGENTS[i]}")
            trained = build_model(entry, EnvConfig.from_dict(ckpt["env_config"]), agent.init)
            if trained.net != agent.net:
                raise ValueError(f"{AGENTS[i]}.init={agent.init!r} was trained with {trained.net}, but this run "
                                 f"asks for {agent.net}; set {AGENTS[i]}.net to match the checkpoint")
            check_compatible(trained.env, cfg.env, agent.init)
            model = trained
        return Learner(model, cfg.ppo, cfg.ppo.loss_weights(agent.aux_coef), agent.lr or cfg.ppo.lr,
                       cfg.seed * 2 + i + 1, self.device)

    def _begin_episodes(self) -> None:
        B, A = self.config.ppo.num_envs, self.config.env.num_agents
        self.obs, _ = self.env.reset()
        self.last = StepInputs.begin(self.config.env, B)
        self.shaped_sum = np.zeros((B, A))  # each env's training reward so far this episode

    # ------------------------------------------------------------------ loop
    def train(self) -> dict:
        cfg = self.config
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2))
        self.log = MetricsLog(self.run_dir, tensorboard=self.tensorboard)
        bar = None
        if self.progress:
            from tqdm import tqdm
            bar = tqdm(total=cfg.num_iterations * cfg.batch_steps, initial=self.step, unit="step", smoothing=0.1)
        last = {}
        self._tick = time.perf_counter()
        try:
            while self.iteration < cfg.num_iterations:
                last = self.train_iteration()
                if bar is not None:
                    bar.update(cfg.batch_steps)
                    bar.set_postfix(sps=f"{last['sps']:.0f}", team=f"{last.get('team_reward', float('nan')):.2f}")
                if cfg.eval_every and self.iteration % cfg.eval_every == 0:
                    last.update(self.evaluate())
                if self.iteration % cfg.save_every == 0 or self.iteration == cfg.num_iterations:
                    self.save()
        finally:
            if bar is not None:
                bar.close()
            self.log.close()
            if self._pool is not None:
                self._pool.shutdown()
                self._pool = None
        return last

    def train_iteration(self) -> dict:
        cfg = self.config
        self.env.penalty_coef = cfg.schedule.penalty_coef(self.step, cfg.env.penalty_coef)
        t0 = time.perf_counter()
        episodes, accuracy = self.collect_rollout()
        t1 = time.perf_counter()
        stats = {}
        for i, result in self._update_learners().items():
            for key, value in result.items():
                stats[f"{AGENTS[i]}/{key}"] = value
            stats[f"{AGENTS[i]}/rollout_goal_accuracy"] = accuracy[i]
        t2 = time.perf_counter()
        self.wall_time += t2 - self._tick  # includes the last evaluation and save
        self._tick = t2
        self.iteration += 1
        self.step += cfg.batch_steps
        row = {"iteration": self.iteration, "penalty_coef": self.env.penalty_coef,
               "shaping_on": float(cfg.schedule.shaping_on(self.step - cfg.batch_steps)),
               "sps": cfg.batch_steps / (t2 - t0), "rollout_sps": cfg.batch_steps / (t1 - t0),
               "update_sps": cfg.batch_steps / max(t2 - t1, 1e-9), "wall_time_s": self.wall_time, **episodes, **stats}
        self.log.write("train", self.step, row)
        return row

    def _update_learners(self) -> dict[int, dict]:
        """Every learner's PPO update on the rollout just collected.

        On a CPU with two learners and two or more torch threads, the two updates run side
        by side, each on its own thread with ``threads // learners`` torch threads: small
        networks use one core each far better than two cores one after the other. The
        learners share nothing (own model, optimizer and random generator), and each one's
        whole update, its bootstrap value included, runs at that thread count, so the result
        is bit for bit the learners updated one after the other with that many threads, on
        any CPU. (It is not bit for bit an update with all the threads: on some CPUs MKL and
        oneDNN split a small matrix product's sum across threads; see docs/TRAINING.md.)
        """
        inputs = {i: self._tensors(i, self._inputs(i)) for i in self.learners}
        threads = torch.get_num_threads()
        if self.device.type != "cpu" or len(self.learners) < 2 or threads < 2:
            return {i: update_learner(lr, inputs[i]) for i, lr in self.learners.items()}
        if self._pool is None:
            self._pool = ThreadPoolExecutor(len(self.learners), thread_name_prefix="learner")
        each = threads // len(self.learners)
        torch.set_num_threads(each)
        try:
            futures = {i: self._pool.submit(update_learner, lr, inputs[i], each) for i, lr in self.learners.items()}
            return {i: f.result() for i, f in futures.items()}
        finally:
            torch.set_num_threads(threads)

    def collect_rollout(self) -> tuple[dict, dict]:
        """``num_steps`` steps of every env; returns episode means and each learner's goal accuracy."""
        cfg, env = self.config, self.env
        B, A = cfg.ppo.num_envs, cfg.env.num_agents
        shaping = cfg.schedule.shaping_on(self.step)
        for learner in self.learners.values():
            learner.start_rollout()
        done_eps: dict[str, list] = {}
        shaped_sum = self.shaped_sum
        hits = {i: 0.0 for i in self.learners}
        for _ in range(cfg.ppo.num_steps):
            true_goal = env.state.goal.copy()
            actions = np.zeros((B, A), dtype=np.int64)
            for i in range(A):
                inp = self._inputs(i, true_goal)
                if i in self.learners:
                    actions[:, i], probs = self.learners[i].act(self._tensors(i, inp))
                    hits[i] += float((probs.argmax(axis=1) == true_goal).mean())
                else:
                    actions[:, i] = self.partners[i].act(inp).actions
            self.obs, rewards, terms, truncs, infos = env.step(actions)
            rewards = self._training_rewards(rewards, infos, shaping)
            shaped_sum += rewards
            done = terms.any(axis=1) | truncs.any(axis=1)  # [B]: every agent's episode ends at once
            self.last.record(actions, infos, done)
            final = self._final_values(infos, done) if done.any() else {}
            for i, learner in self.learners.items():
                learner.record(rewards[:, i], done, true_goal, final.get(i))
            if done.any():
                fi = infos["final_info"]
                for a, name in enumerate(AGENTS):
                    done_eps.setdefault(f"{name}_block_reward", []).extend(fi["episode_block_reward"][done, a])
                    done_eps.setdefault(f"{name}_goal_pickups", []).extend(fi["episode_goal_pickups"][done, a])
                    done_eps.setdefault(f"{name}_wrong_pickups", []).extend(fi["episode_wrong_pickups"][done, a])
                    done_eps.setdefault(f"{name}_training_reward", []).extend(shaped_sum[done, a])
                done_eps.setdefault("team_reward", []).extend(fi["episode_block_reward"][done].sum(axis=1))
                shaped_sum[done] = 0.0
        episodes = {k: float(np.mean(v)) for k, v in done_eps.items()}
        if done_eps:
            episodes["episodes"] = len(done_eps["team_reward"])
        return episodes, {i: h / cfg.ppo.num_steps for i, h in hits.items()}

    def _training_rewards(self, rewards: np.ndarray, infos: dict, shaping: bool) -> np.ndarray:
        """Each agent's learning signal: the env's reward or its own block reward; shaping only while on."""
        shaped = infos["distance_shaping"] + infos["potential_shaping"]
        out = rewards - shaped
        for i, agent in enumerate(self.config.agents):
            if agent.train_reward == "own":
                own = infos["block_reward"][:, i]
                out[:, i] = np.where(own < 0, agent.wrong_weight * own, own)
        return out + shaped if shaping else out

    def _inputs(self, i: int, true_goal: np.ndarray | None = None):
        return self.last.agent_input(self.obs, i, self.env.penalty_coef,
                                     self.env.state.goal.copy() if true_goal is None else true_goal)

    def _tensors(self, i: int, inp) -> dict:
        return step_tensors(inp, self.config.env, i, self.device)

    def _final_values(self, infos: dict, done: np.ndarray) -> dict[int, torch.Tensor]:
        """V(final observation) of ended episodes, so that time-limit truncation is bootstrapped."""
        out = {}
        for i, learner in self.learners.items():
            inp = self.last.agent_input(infos["final_obs"], i, self.env.penalty_coef, self.env.state.goal,
                                        episode_start=np.zeros_like(done))
            value = learner.value(self._tensors(i, inp))
            out[i] = torch.where(torch.as_tensor(done, device=self.device), value, torch.zeros_like(value))
        return out

    # ------------------------------------------------------ evaluate / save
    def evaluate(self) -> dict:
        """The evaluation harness on fixed seeds, plus a few sample episodes saved as replays."""
        cfg = self.config
        seed = 1_000_000 + cfg.seed
        report = evaluate(cfg.env, *self._fresh_policies(), cfg.eval_episodes, seed)
        row = {"team_reward": report["team_reward"]["mean"]}
        for name in AGENTS:
            entry = report["agents"][name]
            for key in ("goal_pickups", "wrong_pickups", "net_pickups"):
                row[f"{name}_{key}"] = entry[key]["mean"]
            if "belief" in entry:
                row[f"{name}_goal_accuracy"] = entry["belief"]["accuracy"]
        self.log.write("eval", self.step, row)
        if cfg.replay_episodes:
            leader, follower = self._fresh_policies()
            batch = run_episodes(cfg.env, leader, follower, cfg.replay_episodes, seed, record_hashes=True)
            record_batch(batch, leader.name, follower.name, leader, follower,
                         self.run_dir / "replays" / f"step_{self.step:09d}", source="train",
                         meta={"train_step": self.step, "run": str(self.run_dir)})
        return {f"eval/{k}": v for k, v in row.items()}

    def _fresh_policies(self) -> list:
        """Policies for a separate evaluation: partners are rebuilt so the training batch's state is untouched."""
        out = []
        for i, agent in enumerate(self.config.agents):
            if i in self.learners:
                out.append(NetPolicy(self.learners[i].model, name=f"{AGENTS[i]}@{self.step}"))
            else:
                out.append(make_policy(agent.policy, role=AGENTS[i]))
        return out

    def checkpoint_payload(self) -> dict:
        agents = {name: None for name in AGENTS}
        for i, learner in self.learners.items():
            agents[AGENTS[i]] = agent_entry(learner.model, learner.optimizer)
        state = {
            "format": TRAINER_STATE_FORMAT,
            "env_state": {f.name: getattr(self.env.state, f.name) for f in dataclasses.fields(self.env.state)},
            "penalty_coef": self.env.penalty_coef, "last_step": self.last.state_dict(), "shaped_sum": self.shaped_sum,
            "learners": {AGENTS[i]: {"recurrent": None if lr.state is None else list(lr.state),
                                     "generator": lr.generator.get_state()} for i, lr in self.learners.items()},
            "partners": {AGENTS[i]: {"describe": describe_agent(p.describe()), "state": p.state_dict()}
                         for i, p in self.partners.items()},
            "torch_rng": torch.get_rng_state(),
        }
        return {"config": self.config.to_dict(), "env_config": self.config.env.to_dict(), "step": self.step,
                "iteration": self.iteration, "wall_time_s": self.wall_time, "device": device_name(self.device),
                "agents": agents, "trainer_state": to_tensors(state)}

    def save(self) -> Path:
        payload = self.checkpoint_payload()
        folder = self.run_dir / "checkpoints"
        path = save_checkpoint(folder / f"step_{self.step:09d}.pt", payload)
        save_checkpoint(folder / "latest.pt", payload)
        return path

    def restore(self, path: str | Path) -> None:
        """Continue from a checkpoint of this run: weights, optimizers, env, recurrent states, RNGs."""
        ckpt = load_checkpoint(path)
        if ckpt.get("trainer_state") is None:
            raise ValueError(f"{path} is an exported policy (no trainer state); resume from a run's checkpoints/")
        for i, learner in self.learners.items():
            entry = ckpt["agents"].get(AGENTS[i])
            if entry is None:
                raise ValueError(f"{path} holds no trained {AGENTS[i]}, but this run trains one")
            load_weights(learner.model, entry["state_dict"], str(path))
            learner.optimizer.load_state_dict(entry["optimizer"])
        state = ckpt["trainer_state"]
        if not isinstance(state, dict) or state.get("format") != TRAINER_STATE_FORMAT:
            raise ValueError(f"{path} holds a trainer state this colorgrid cannot resume (written by an older version, "
                             f"as a pickle); start a new run with its weights: --set follower.init={path}")
        self.obs = self.env.load_state(EnvState(**to_arrays(state["env_state"])))
        self.env.penalty_coef = float(state["penalty_coef"])
        self.last.load_state_dict(to_arrays(state["last_step"]))
        self.shaped_sum = to_arrays(state["shaped_sum"])
        for i, learner in self.learners.items():
            saved = state["learners"][AGENTS[i]]
            learner.state = None if saved["recurrent"] is None else tuple(t.to(self.device) for t in saved["recurrent"])
            learner.generator.set_state(saved["generator"])
        for i, partner in self.partners.items():
            saved = state["partners"][AGENTS[i]]
            if saved["describe"] != describe_agent(partner.describe()):
                raise ValueError(f"{path}: the {AGENTS[i]} partner was {saved['describe']}, now it is "
                                 f"{describe_agent(partner.describe())}; resume with the same partner")
            partner.load_state_dict(saved["state"])
        torch.set_rng_state(state["torch_rng"])
        self.step, self.iteration = int(ckpt["step"]), int(ckpt["iteration"])
        self.wall_time = float(ckpt.get("wall_time_s", 0.0))
