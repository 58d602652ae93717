"""Training configuration: frozen dataclasses, validated on construction, loadable from preset files.

A run is one ``TrainConfig``: the environment (a team of any shape), one ``AgentConfig`` (``train.agent_config``) per
role (``leader``: every leader, ``follower``: every follower; each agent learns, plays a
frozen checkpoint or a scripted policy, and a role's learners may share one network), the
PPO settings (defaults are the paper's table), the schedules, and where and how often to
log, evaluate and save. Presets in ``train/presets/*.json`` hold only the fields that differ
from these defaults.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

from colorgrid import configkit
from colorgrid.config import ROLES, EnvConfig
from colorgrid.configkit import (ConfigBase, ConfigError, Presets, check_bool, check_choice, check_int, check_number,
                                 check_strings, fail, merge, override_dict)
from colorgrid.enums import Role
from colorgrid.policies.names import policy_names, read_name
# one role's settings, named here too (train.config.NetConfig and the rest, as before the split)
from train.agent_config import (ARCHS, GOAL_FUSION_ALIASES, GOAL_FUSIONS, AgentConfig, NetConfig,  # noqa: F401
                                between)

PRESETS_DIR = Path(__file__).parent / "presets"
DEVICES = ("auto", "cpu", "cuda")


TrainConfigError = ConfigError
"""A training setting is invalid (the toolkit's ``ConfigError``): the message names the field from the
config's root (``ppo.lr=-1 is invalid: ...``), the value and what is allowed."""


def eval_stream(partner: str) -> str:
    """The training log's stream of the evaluation beside ``partner`` (``eval_partners``): ``eval_`` and the name with
    every character but letters and digits as ``_`` (``population:people#held_out``: ``eval_population_people_held_out``)."""
    import re

    return "eval_" + re.sub(r"[^A-Za-z0-9]+", "_", partner).strip("_")


@dataclass(frozen=True)
class PPOConfig:
    """PPO settings; defaults are the paper's table."""

    lr: float = 1e-4
    """Adam's learning rate (every learner; ``AgentConfig.lr`` overrides it for one)."""
    num_envs: int = 16
    """Environments stepped together in a rollout."""
    num_steps: int = 128
    """Steps of each env per rollout (a PPO iteration collects ``num_envs * num_steps`` env steps)."""
    gamma: float = 0.99
    """Discount factor."""
    gae_lambda: float = 0.95
    """GAE's lambda: the bias-variance trade-off of the advantage estimates."""
    num_minibatches: int = 4
    """Minibatches per epoch; must divide ``num_envs`` (recurrent minibatches are whole envs)."""
    update_epochs: int = 4
    """Passes over each rollout."""
    clip_coef: float = 0.2
    """PPO's clipping range for the probability ratio (and for the value, with ``clip_vloss``)."""
    clip_vloss: bool = True
    """Clip the value loss around the rollout's values."""
    ent_coef: float = 0.01
    """Weight of the entropy bonus."""
    vf_coef: float = 0.5
    """Weight of the value loss."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip."""
    target_kl: float | None = 0.01
    """Stop an update's epochs early once the approximate KL passes this (null: never)."""
    norm_adv: bool = True
    """Normalise advantages within each minibatch."""

    def __post_init__(self):
        for name, hi in (("num_envs", 65536), ("num_steps", 65536), ("num_minibatches", 65536),
                         ("update_epochs", 1000)):
            check_int(self, name, 1, hi)
        if self.num_envs % self.num_minibatches:
            fail(self, "num_minibatches", f"must divide ppo.num_envs={self.num_envs} (recurrent minibatches are "
                                          f"whole envs)")
        check_number(self, "lr", "a number in (0, 1)", between(0.0, 1.0, True, True))
        for name in ("gamma", "gae_lambda"):
            check_number(self, name, "a number in [0, 1]", between(0.0, 1.0))
        for name in ("clip_coef", "ent_coef", "vf_coef", "max_grad_norm"):
            check_number(self, name, "a non-negative number", between(0.0, math.inf))
        check_number(self, "target_kl", "a positive number, or null to never stop early",
                     between(0.0, math.inf, low_open=True), optional=True)
        for name in ("clip_vloss", "norm_adv"):
            check_bool(self, name)

    def loss_weights(self, aux_coef: float):
        """The loss's ``LossWeights``: these settings and the agent's auxiliary coefficient."""
        from train.ppo import LossWeights  # torch, only when training

        return LossWeights(self.clip_coef, self.clip_vloss, self.ent_coef, self.vf_coef, aux_coef, self.norm_adv)


@dataclass(frozen=True)
class ScheduleConfig:
    """Schedules over env steps (counted across the whole batch)."""

    penalty_start: int | None = None
    """Penalty annealing: the wrong-block penalty coefficient is 0 until this step ..."""
    penalty_end: int | None = None
    """... and rises linearly to 1 at this step (both None: no annealing, the env's own coefficient)."""
    shaping_steps: int | None = None
    """Reward-shaping terms (set in the env config) count toward training rewards only for this many steps."""

    def __post_init__(self):
        for name in ("penalty_start", "penalty_end", "shaping_steps"):
            check_int(self, name, 0, optional=True)
        if (self.penalty_start is None) != (self.penalty_end is None):
            fail(self, "penalty_end", "set both penalty_start and penalty_end, or neither")
        if self.penalty_start is not None and not self.penalty_start <= self.penalty_end:
            fail(self, "penalty_start", f"0 <= penalty_start <= penalty_end={self.penalty_end}")

    def penalty_coef(self, step: int, default: float) -> float:
        if self.penalty_start is None:
            return default
        if step < self.penalty_start:
            return 0.0
        if step >= self.penalty_end:
            return 1.0
        return (step - self.penalty_start) / max(1, self.penalty_end - self.penalty_start)

    def shaping_on(self, step: int) -> bool:
        return self.shaping_steps is None or step < self.shaping_steps


@dataclass(frozen=True)
class TrainConfig(ConfigBase):
    """One training run."""

    NOTES = ("description",)
    """Keys a preset or config file may hold for people, not settings (``configkit.from_dict`` drops them)."""

    env: EnvConfig = field(default_factory=EnvConfig)
    """The environment; ``env.num_leaders`` and ``env.num_followers`` set the team."""
    leader: AgentConfig = field(default_factory=AgentConfig)
    """Every leader's settings."""
    follower: AgentConfig = field(default_factory=AgentConfig)
    """Every follower's settings."""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    total_steps: int = 1_000_000
    """Env steps to train for (iterations x num_envs x num_steps, rounded up to whole iterations)."""
    seed: int = 0
    eval_every: int = 10
    """Evaluate every this many iterations with the evaluation harness (0: never)."""
    eval_episodes: int = 32
    eval_partners: tuple[str, ...] = ()
    """More evaluations at each ``eval_every``, on the same fixed seeds, each with every agent that does not learn
    played by the named policy instead (``astar``, ``bayes``, ``population:people#held_out``, a checkpoint): so
    learners trained beside different partners are judged beside the same ones. Logged as the stream
    ``eval_NAME`` (``eval_NAME/follower_net_pickups``, ...; ``eval_stream`` gives NAME)."""
    replay_episodes: int = 2
    """Sample episodes saved as replays at each evaluation."""
    save_every: int = 50
    """Write a checkpoint every this many iterations (and always at the end)."""
    device: str = "auto"
    threads: int = 0
    """Torch CPU threads (0: all cores)."""
    update_processes: bool = True
    """Where learners update side by side on a CPU at one torch thread each (as many learners as threads: two on
    two cores), each learner after the first updates in a process of its own, its weights in shared
    memory (``train/update_process.py``): threads of one process hand Python's GIL to each other at every
    operation and update about 15% slower. The same results bit for bit; false: threads."""
    keep_freed_memory: bool = False
    """On a CPU, ask glibc's malloc to keep freed memory (``train/memory.py``): large networks (the
    paper's) reuse their ~100 MB activations instead of page-faulting them in every minibatch,
    1.6x faster; the process then keeps its peak memory. On in the ``paper_*`` presets."""

    def __post_init__(self):
        for role in ROLES:
            section, count = self.section(role), self.role_size(role)
            if section.policies and len(section.policies) != count:
                fail(self, f"{role}.policies", f"one policy per {role} (env.num_{role}s={count}), or [] to give "
                                               f"every {role} {role}.policy", section.policies)
            learning = section.agent_policies(count).count("learn")
            if section.share_network and learning < 2:
                fail(self, f"{role}.share_network", f"false unless two or more {role}s learn (this team has "
                                                    f"{learning} learning {role}{'' if learning == 1 else 's'})",
                     section.share_network)
        policies = tuple(a.policy for a in self.agents)
        if "learn" not in policies:
            fail(self, "leader.policy/follower.policy", "at least one agent must have policy='learn'", policies)
        check_choice(self, "device", DEVICES, f"choose one of {list(DEVICES)}")
        for name, lo in (("total_steps", 1), ("seed", 0), ("eval_every", 0), ("eval_episodes", 1),
                         ("replay_episodes", 0), ("save_every", 1), ("threads", 0)):
            check_int(self, name, lo)
        check_bool(self, "keep_freed_memory")
        check_bool(self, "update_processes")
        if self.replay_episodes > self.eval_episodes:
            fail(self, "replay_episodes", f"at most eval_episodes={self.eval_episodes}")
        names = policy_names()
        check_strings(self, "eval_partners", distinct=True, allowed=f"a list of distinct policies to evaluate beside: "
                                                                    f"one of {names}, a population or a checkpoint")
        for spec in self.eval_partners:
            if spec == "learn" or read_name(spec) is None:
                fail(self, "eval_partners", f"{spec!r} is not a policy to evaluate beside: one of {names} (with "
                                            f"parameters as name:key=value,...), population:NAME[#PART] or a .pt file")
        if self.eval_partners and all(a.policy == "learn" for a in self.agents):
            fail(self, "eval_partners", "[] when every agent learns: an evaluation partner stands in for the agents "
                                        "that do not")
        if len({eval_stream(s) for s in self.eval_partners}) != len(self.eval_partners):
            fail(self, "eval_partners", "partners whose stream names (eval_stream) differ")

    def section(self, role: str) -> AgentConfig:
        """The settings of every agent of ``role`` (``leader`` or ``follower``)."""
        return self.leader if role == Role.LEADER else self.follower

    def role_size(self, role: str) -> int:
        return self.env.num_leaders if role == Role.LEADER else self.env.num_followers

    @cached_property
    def agents(self) -> tuple[AgentConfig, ...]:
        """Each agent's settings, in index order: its role's section, with its own policy where
        ``policies`` gives one (the 1:1 team: ``(leader, follower)``)."""
        out = []
        for role in ROLES:
            section = self.section(role)
            for policy in section.agent_policies(self.role_size(role)):
                if policy == section.policy and not section.policies:
                    out.append(section)
                else:
                    learns = policy == "learn"
                    out.append(dataclasses.replace(section, policy=policy, policies=(),
                                                   init=section.init if learns else None,
                                                   aux_target=section.aux_target if learns else "goal"))
        return tuple(out)

    @cached_property
    def networks(self) -> tuple[tuple[str, tuple[int, ...]], ...]:
        """The networks trained here, in the order of their first agent: ``(name, agents it plays)``.

        One per learning agent, named after it (``env.agent_names``); with ``share_network``, one for
        the role's learning agents together, named after the role.
        """
        names, roles = self.env.agent_names, self.env.roles
        out: dict[str, list[int]] = {}
        for i, agent in enumerate(self.agents):
            if agent.learns:
                key = roles[i] if self.section(roles[i]).share_network else names[i]
                out.setdefault(key, []).append(i)
        return tuple((name, tuple(agents)) for name, agents in out.items())

    @property
    def batch_steps(self) -> int:
        return self.ppo.num_envs * self.ppo.num_steps

    @property
    def num_iterations(self) -> int:
        return -(-self.total_steps // self.batch_steps)

    @property
    def end_step(self) -> int:
        """The step a run ends at: ``total_steps`` rounded up to a whole PPO iteration."""
        return self.num_iterations * self.batch_steps

    def to_dict(self) -> dict:
        return configkit.to_dict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "TrainConfig":
        return from_dict(data)


OVERRIDE_EXAMPLE = "ppo.lr=3e-4 or follower.net.lstm=true"
PRESETS = Presets(folder=PRESETS_DIR, what="preset")
"""Training presets: one JSON file each in ``train/presets/``, holding the fields that differ from the defaults."""


def from_dict(data: dict) -> TrainConfig:
    """A TrainConfig from nested plain data (as in preset files); unknown keys are errors."""
    return configkit.from_dict(TrainConfig, data)


def resolve(*layers: dict, overrides=()) -> TrainConfig:
    """The TrainConfig that settings in layers describe, each on top of the last: a preset's data, a config file's
    (or a saved run's), then ``KEY=VALUE`` overrides (``--set``). ``colorgrid train`` and the sweep file resolve
    their configs here (``configkit.resolve``)."""
    return configkit.resolve(TrainConfig, *layers, overrides=overrides, example=OVERRIDE_EXAMPLE)


def preset_names() -> list[str]:
    return PRESETS.names()


def load_preset(name: str) -> dict:
    """A preset's plain data by name (``train/presets/<name>.json``) or by file path."""
    return PRESETS.load(name)


def parse_override(text: str) -> dict:
    """``a.b.c=value`` to ``{"a": {"b": {"c": value}}}``; the value is JSON if it parses, else a string."""
    return override_dict(text, TrainConfig, example=OVERRIDE_EXAMPLE)
