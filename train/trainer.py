"""IPPO for ColorGrid, top to bottom: build agents, then loop rollout -> update -> log -> evaluate -> save.

The team may have any shape (``env.num_leaders``, ``env.num_followers``). Each learning
agent has its own actor-critic and optimizer (independent PPO), or the learning agents of a
role share one (``share_network``: one network acts for all of them in one batch and updates
on all their experience); an agent that does not learn is any ``Policy``: scripted (A*,
idle, ...) or a frozen checkpoint. Everything that decides what happens next (env state,
recurrent states, last-step inputs, RNGs) is saved in checkpoints, so a resumed run
continues exactly as if never stopped.
"""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path
from typing import Callable, Generator

import numpy as np
import torch

from colorgrid.env import BatchEnv
from colorgrid.policies import make_policy
from colorgrid.rollout import run_team
from colorgrid.step_inputs import StepInputs
from colorgrid.evaluate import record_team, summarize
from train.checkpoint import restore_trainer, save_checkpoint, trainer_payload
from train.config import TrainConfig, eval_stream
from train.inputs import rows_of_agents, step_tensors
from train.learner import Learner
from train.memory import keep_freed_memory
from train.metrics import MetricsLog, episode_columns, episode_totals, evaluation_row
from train.nets import ActorCritic
from train.placement import Placement, device_name, pick_device
from train.policy import NetPolicy
from train.warm_start import warm_start


class Trainer:
    """One ``TrainConfig``'s run in ``run_dir``: ``train()`` loops rollout -> update -> log -> evaluate -> save;
    where the learners run is its ``placement``'s business (``train.placement``)."""

    def __init__(self, config: TrainConfig, run_dir: str | Path, progress: bool = True, tensorboard: bool = True,
                 keep_steps: bool = True):
        """``keep_steps``: keep every saved checkpoint (``step_*.pt``) beside ``latest.pt``; false keeps only the
        latest (a sweep's trials: Ray Tune keeps its own copies)."""
        self.config, self.run_dir, self.progress, self.keep_steps = config, Path(run_dir), progress, keep_steps
        if config.threads:
            torch.set_num_threads(config.threads)
        torch.manual_seed(config.seed)
        self.device = pick_device(config.device)
        if config.keep_freed_memory and self.device.type == "cpu" and not keep_freed_memory():
            warnings.warn("keep_freed_memory=true needs glibc's malloc (Linux); memory is used as usual", stacklevel=2)
        self.env = BatchEnv(config.env, num_envs=config.ppo.num_envs, seed=config.seed)
        self.names = config.env.agent_names
        networks = {agents[0]: (name, agents) for name, agents in config.networks}
        self.learners: dict[int, Learner] = {}  # by the first agent each network plays
        self.partners: dict[int, object] = {}  # by agent
        for i, agent in enumerate(config.agents):
            if i in networks:
                self.learners[i] = self._make_learner(*networks[i])
            elif not agent.learns:
                self.partners[i] = self._watcher(agent.policy, i)
        # a learner's auxiliary target, when it is another policy's belief: that policy watches from the agent's seat
        self.teachers = {a: self._watcher(config.agents[a].aux_target, a) for lr in self.learners.values()
                         for a in lr.agents if config.agents[a].aux_target != "goal"}
        self.step, self.iteration = 0, 0
        self.wall_time = 0.0  # wall-clock seconds of training so far, across resumes
        self._tick = time.perf_counter()
        self._begin_episodes()
        self.tensorboard = tensorboard
        self.log: MetricsLog | None = None
        self.placement = Placement(self.learners, self.device, config.update_processes)  # where the learners run

    def _make_learner(self, name: str, agents: tuple[int, ...]) -> Learner:
        """The network ``name`` that plays ``agents`` (one, or a role's learners sharing it), new or warm-started."""
        cfg, agent = self.config, self.config.agents[agents[0]]
        role = cfg.env.roles[agents[0]]
        if agent.init is None:
            model = ActorCritic(agent.net, cfg.env, agents if len(agents) > 1 else agents[0])
        else:
            model = warm_start(agent.init, f"{role}.init", name, agents, agent.net, cfg.env)
        return Learner(model, cfg.ppo, cfg.ppo.loss_weights(agent.aux_coef), agent.lr or cfg.ppo.lr,
                       cfg.seed * 2 + agents[0] + 1, self.device, name)

    def _watcher(self, spec: str, i: int):
        """Policy ``spec`` in agent ``i``'s seat over every training env (a partner that acts, or a teacher)."""
        policy = make_policy(spec, role=self.names[i])
        policy.reset(self.config.env, self.config.ppo.num_envs, i, seed=self.config.seed)
        return policy

    def _begin_episodes(self) -> None:
        B, A = self.config.ppo.num_envs, self.config.env.num_agents
        self.obs, _ = self.env.reset()
        self.last = StepInputs.begin(self.config.env, B)
        self.shaped_sum = np.zeros((B, A))  # each env's training reward so far this episode

    # ------------------------------------------------------------------ loop
    def train(self, on_iteration: Callable[[dict, Path | None], None] | None = None,
              stop: Callable[[], bool] | None = None) -> dict:
        """Train to ``total_steps``; ``on_iteration(row, saved)`` is called after each iteration with its log row
        (and evaluation) and the checkpoint it saved (``latest.pt``), or None. ``stop()``, asked after each
        iteration: true ends training there, with a checkpoint of that iteration (``colorgrid train``'s Ctrl+C).
        This run alone is a ``Pack`` of one (``train.pack``)."""
        from train.pack import Pack

        report = None if on_iteration is None else (lambda done: on_iteration(*done[0]))
        return Pack([self]).train(report, stop)[0]

    def start(self) -> None:
        """Before the first iteration of ``train``: the run folder, its config and its logs."""
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / "config.json").write_text(json.dumps(self.config.to_dict(), indent=2))
        self.log = MetricsLog(self.run_dir, tensorboard=self.tensorboard)
        self._tick = time.perf_counter()

    @property
    def finished(self) -> bool:
        """Whether this run has trained all its iterations."""
        return self.iteration >= self.config.num_iterations

    def after_iteration(self, row: dict, stopping: bool) -> Path | None:
        """Evaluate and save where the config says (always when ``stopping``); returns the checkpoint saved."""
        cfg = self.config
        if cfg.eval_every and self.iteration % cfg.eval_every == 0:
            row.update(self.evaluate())
        if self.iteration % cfg.save_every == 0 or self.iteration == cfg.num_iterations or stopping:
            return self.save()
        return None

    def close(self) -> None:
        """End the threads and processes the learners update on (``train`` does when it ends); the next update
        starts them again."""
        self.placement.close()

    # where the placement keeps its threads and processes (tests look at them)
    _pool = property(lambda self: self.placement._pool)
    _processes = property(lambda self: self.placement._processes)
    _stacked = property(lambda self: self.placement._stacked)

    def train_iteration(self) -> dict:
        """One PPO iteration of this run alone: a ``Pack`` of one (``train.pack``)."""
        from train.pack import Pack

        return Pack([self]).train_iteration()[0]

    def begin_iteration(self) -> None:
        """Set what the schedules say for the iteration about to run (the wrong-block penalty's coefficient)."""
        self.env.penalty_coef = self.config.schedule.penalty_coef(self.step, self.config.env.penalty_coef)

    def end_iteration(self, episodes: dict, accuracy: dict, results: dict[int, dict], t0: float, t1: float,
                      t2: float) -> dict:
        """Count the iteration that rolled out between ``t0`` and ``t1`` and updated (``results``, by learner key)
        until ``t2``, and log its row."""
        cfg = self.config
        stats = {}
        for i, result in results.items():
            learner = self.learners[i]
            for key, value in result.items():
                stats[f"{learner.name}/{key}"] = value
            for a in learner.agents:
                stats[f"{self.names[a]}/rollout_goal_accuracy"] = accuracy[a]
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
        """Every learner's PPO update on the rollout just collected, wherever its placement runs it."""
        return self.placement.update(self.update_inputs())

    def update_inputs(self) -> dict[int, dict]:
        """Every learner's network inputs now, by learner key: what its update bootstraps its values from."""
        return {i: self._learner_tensors(lr) for i, lr in self.learners.items()}

    def collect_rollout(self) -> tuple[dict, dict]:
        """``num_steps`` steps of every env, the learners acting where this run's placement puts them; returns
        episode means and each learning agent's goal accuracy (``rollout``)."""
        with self.placement.acting() as act:
            rollout = self.rollout()
            inputs_of = next(rollout)
            while True:
                try:
                    inputs_of = rollout.send(act(inputs_of))
                except StopIteration as done:
                    return done.value

    def rollout(self) -> Generator[Callable[[Learner], dict], dict, tuple[dict, dict]]:
        """``num_steps`` steps of every env, as a generator: at each step it yields ``inputs_of(learner)`` (the
        network inputs of each of this run's learners) and is sent back what the learners chose, by learner key
        (``Placement.acting``'s ``act`` gives it; a ``Pack`` acts for several runs at once). Returns episode means
        and each learning agent's goal accuracy."""
        cfg, env = self.config, self.env
        B, A = cfg.ppo.num_envs, cfg.env.num_agents
        shaping = cfg.schedule.shaping_on(self.step)
        for learner in self.learners.values():
            learner.start_rollout()
        done_eps: dict[str, list] = {}
        shaped_sum = self.shaped_sum
        hits = {a: 0 for learner in self.learners.values() for a in learner.agents}  # steps its goal head was right
        for _ in range(cfg.ppo.num_steps):
            true_goal = env.state.goal.copy()
            actions = np.zeros((B, A), dtype=np.int64)
            targets = {i: self._aux_targets(lr, true_goal) for i, lr in self.learners.items()}
            acted = yield lambda lr, goal=true_goal: self._learner_tensors(lr, goal)
            for i, learner in self.learners.items():
                chosen, probs = acted[i]
                for k, a in enumerate(learner.agents):  # rows are agent-major: agent k's envs are rows kB..(k+1)B
                    actions[:, a] = chosen[k * B:(k + 1) * B]
                    hits[a] += np.count_nonzero(probs[k * B:(k + 1) * B].argmax(axis=1) == true_goal)
            for i, partner in self.partners.items():
                actions[:, i] = partner.act(self._inputs(i, true_goal)).actions
            self.obs, rewards, terms, truncs, infos = env.step(actions)
            rewards = self._training_rewards(rewards, infos, shaping)
            shaped_sum += rewards
            done = terms.any(axis=1) | truncs.any(axis=1)  # [B]: every agent's episode ends at once
            self.last.record(actions, infos, done)
            final = self._final_values(infos, done) if done.any() else {}
            for i, learner in self.learners.items():
                k = len(learner.agents)
                learner.record(rewards[:, learner.agents].T.reshape(-1), np.tile(done, k), np.tile(true_goal, k),
                               final.get(i), targets[i])
            if done.any():
                totals = episode_totals(infos["final_info"], done, shaped_sum)
                for key, values in episode_columns(cfg.env, totals).items():
                    done_eps.setdefault(key, []).extend(values)
                done_eps.setdefault("team_reward", []).extend(totals["block_reward"].sum(axis=1))
                shaped_sum[done] = 0.0
        episodes = {k: float(np.mean(v)) for k, v in done_eps.items()}
        if done_eps:
            episodes["episodes"] = len(done_eps["team_reward"])
        return episodes, {a: h / (cfg.ppo.num_steps * B) for a, h in hits.items()}

    def _aux_targets(self, learner: Learner, true_goal: np.ndarray) -> np.ndarray | None:
        """The teachers' beliefs over the goal for ``learner``'s rows (agent-major), or None: the true goal."""
        if learner.agents[0] not in self.teachers:
            return None
        beliefs = []
        for a in learner.agents:
            belief = self.teachers[a].act(self._inputs(a, true_goal)).goal_probs
            if belief is None:
                raise ValueError(f"{self.config.env.roles[a]}.aux_target={self.config.agents[a].aux_target!r} keeps "
                                 f"no belief over the goal to distil; use a follower that does (bayes, "
                                 f"bayes-people, a trained .pt)")
            beliefs.append(belief)
        return np.concatenate(beliefs)

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

    def _learner_tensors(self, learner: Learner, true_goal: np.ndarray | None = None, obs: dict | None = None,
                         episode_start: np.ndarray | None = None) -> dict:
        """The network inputs of every agent ``learner`` plays, as its rows (agent-major); ``obs`` and
        ``episode_start`` replace the current observations and the recorded starts."""
        goal = self.env.state.goal.copy() if true_goal is None else true_goal
        return rows_of_agents([
            step_tensors(self.last.agent_input(self.obs if obs is None else obs, a, self.env.penalty_coef, goal,
                                               episode_start=episode_start), self.config.env, a, self.device,
                         progress=learner.model.net.leader_progress, copy_obs=False)
            for a in learner.agents])

    def _final_values(self, infos: dict, done: np.ndarray) -> dict[int, torch.Tensor]:
        """V(final observation) of ended episodes, so that time-limit truncation is bootstrapped."""
        out = {}
        for i, learner in self.learners.items():
            value = learner.value(self._learner_tensors(learner, self.env.state.goal, infos["final_obs"],
                                                        np.zeros_like(done)))
            ended = torch.as_tensor(np.tile(done, len(learner.agents)), device=self.device)
            out[i] = torch.where(ended, value, torch.zeros_like(value))
        return out

    # ------------------------------------------------------ evaluate / save
    def evaluate(self) -> dict:
        """The evaluation harness on fixed seeds, plus a few sample episodes saved as replays."""
        cfg = self.config
        seed = 1_000_000 + cfg.seed
        row = evaluation_row(cfg.env, summarize(run_team(cfg.env, self._fresh_policies(), cfg.eval_episodes, seed)))
        self.log.write("eval", self.step, row)
        if cfg.replay_episodes:
            policies = self._fresh_policies()
            batch = run_team(cfg.env, policies, cfg.replay_episodes, seed, record_hashes=True)
            record_team(batch, [p.name for p in policies], policies, self.run_dir / "replays" / f"step_{self.step:09d}",
                        source="train", meta={"train_step": self.step, "run": str(self.run_dir)})
        out = {f"eval/{k}": v for k, v in row.items()}
        for partner in cfg.eval_partners:  # the same seeds beside other partners
            stream = eval_stream(partner)
            beside = evaluation_row(cfg.env, summarize(run_team(cfg.env, self._fresh_policies(partner),
                                                                cfg.eval_episodes, seed)))
            self.log.write(stream, self.step, beside)
            out.update({f"{stream}/{k}": v for k, v in beside.items()})
        return out

    def _fresh_policies(self, partner: str | None = None) -> list:
        """One policy per agent for a separate evaluation: partners are rebuilt so the training batch's state is
        untouched (or ``partner`` plays every agent that does not learn); a shared network plays each of its agents
        through a policy of its own."""
        out = []
        for i, agent in enumerate(self.config.agents):
            learner = next((lr for lr in self.learners.values() if i in lr.agents), None)
            if learner is not None:
                out.append(NetPolicy(learner.model, name=f"{self.names[i]}@{self.step}"))
            else:
                out.append(make_policy(partner or agent.policy, role=self.names[i]))
        return out

    def checkpoint_payload(self) -> dict:
        """The resumable checkpoint of this trainer now (``train.checkpoint.trainer_payload``)."""
        return trainer_payload(self, device_name(self.device))

    def save(self) -> Path:
        """Write the resumable checkpoint ``checkpoints/latest.pt`` (and ``step_*.pt`` with ``keep_steps``)."""
        payload = self.checkpoint_payload()
        folder = self.run_dir / "checkpoints"
        if self.keep_steps:
            save_checkpoint(folder / f"step_{self.step:09d}.pt", payload)
        return save_checkpoint(folder / "latest.pt", payload)

    def restore(self, path: str | Path) -> None:
        """Continue from a checkpoint of this run: weights, optimizers, env, recurrent states, RNGs
        (``train.checkpoint.restore_trainer``)."""
        restore_trainer(self, path)
