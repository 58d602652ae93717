"""Training configuration: frozen dataclasses, validated on construction, loadable from preset files.

A run is one ``TrainConfig``: the environment, one ``AgentConfig`` per agent (learn,
freeze a checkpoint, or play a scripted policy), the PPO settings (defaults are the
paper's table), the schedules, and where and how often to log, evaluate and save.
Presets in ``train/presets/*.json`` hold only the fields that differ from these defaults.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from colorgrid.config import AGENTS, EnvConfig
from colorgrid.files import JSONFileError, read_json_object

PRESETS_DIR = Path(__file__).parent / "presets"
ARCHS = ("fast", "paper")
GOAL_FUSIONS = ("early", "late", "planes")
DEVICES = ("auto", "cpu", "cuda")


class TrainConfigError(ValueError):
    """A training setting is invalid; the message names the field, the value and what is allowed.

    ``field`` is the setting's name within the dataclass that raised it (None for errors that
    are not about one field); ``within`` names it from the config's root.
    """

    def __init__(self, message: str, field: str | None = None, detail: str = ""):
        super().__init__(message)
        self.field, self.detail = field, detail

    def within(self, section: str) -> "TrainConfigError":
        """The same error with the field named from its section: ``aux_coef`` -> ``follower.aux_coef``."""
        if self.field is None or not section:
            return self
        name = f"{section}.{self.field}"
        return TrainConfigError(name + self.detail, name, self.detail)


def _fail(name: str, value, allowed: str):
    detail = f"={value!r} is invalid: {allowed}"
    raise TrainConfigError(name + detail, name, detail)


def _check_int(name: str, value, lo: int, hi: int | None = None, optional: bool = False) -> None:
    """An int (not a bool) in [lo, hi]; ``optional``: or None."""
    if optional and value is None:
        return
    if isinstance(value, bool) or not isinstance(value, int) or value < lo or (hi is not None and value > hi):
        allowed = f"an integer in [{lo}, {hi}]" if hi is not None else f"an integer >= {lo}"
        _fail(name, value, allowed + (" or null" if optional else ""))


def _check_number(name: str, value, allowed: str, within=lambda v: True, optional: bool = False) -> None:
    """A finite int or float (not a bool) for which ``within`` holds; ``optional``: or None. ``allowed`` says which."""
    if optional and value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not within(value):
        _fail(name, value, allowed)


def _check_bool(name: str, value) -> None:
    if not isinstance(value, bool):
        _fail(name, value, "true or false")


@dataclass(frozen=True)
class NetConfig:
    """The actor-critic of one agent."""

    arch: str = "fast"
    """``fast``: egocentric view, downsampled in the first conv (CPU-friendly). ``paper``: the paper's exact net."""
    lstm: bool = False
    """Add an LSTM core (trained with truncated BPTT over whole rollouts)."""
    lstm_size: int = 128
    hidden: int = 128
    """Width of the fast net's trunk (the paper net is fixed at 192)."""
    goal_fusion: str = "early"
    """Where the goal joins: ``early`` (one-hot with the conv features), ``late`` (before the heads) or
    ``planes`` (the block planes are split into goal-colored blocks and the rest, as two extra input planes;
    with ``belief_input`` the split uses the agent's own belief, from an LSTM over the last-step inputs)."""
    extra_inputs: bool = False
    """Also feed last step's team reward, both agents' actions and the colors they collected."""
    belief_input: bool = False
    """Feed the agent's own goal prediction (detached softmax of the auxiliary head) to its policy and value heads."""

    def __post_init__(self):
        if self.arch not in ARCHS:
            _fail("arch", self.arch, f"choose one of {list(ARCHS)}")
        if self.goal_fusion not in GOAL_FUSIONS:
            _fail("goal_fusion", self.goal_fusion, f"choose one of {list(GOAL_FUSIONS)}")
        for name in ("lstm_size", "hidden"):
            _check_int(name, getattr(self, name), 1, 4096)
        for name in ("lstm", "extra_inputs", "belief_input"):
            _check_bool(name, getattr(self, name))
        if self.goal_fusion == "planes" and self.belief_input and not (self.lstm and self.extra_inputs):
            _fail("belief_input", self.belief_input, "with goal_fusion='planes' the belief comes from an LSTM "
                  "over the last-step inputs: set net.lstm=true and net.extra_inputs=true too")


@dataclass(frozen=True)
class AgentConfig:
    """How one agent takes part in a run."""

    policy: str = "learn"
    """``learn`` (trained here), a scripted policy name (``astar``, ``idle``, ``bayes``, ...), or a checkpoint path (frozen)."""
    init: str | None = None
    """For ``learn``: warm-start weights (and network settings) from this checkpoint."""
    net: NetConfig = field(default_factory=NetConfig)
    aux_coef: float = 0.2
    """Weight kappa of the auxiliary goal-prediction cross-entropy (0 turns it off)."""
    lr: float | None = None
    """Learning rate for this agent; None uses ``ppo.lr``."""
    train_reward: str = "env"
    """What this agent learns from: ``env`` (the env's reward for it: the team reward in ``shared`` mode) or
    ``own`` (its own block reward, plus shaping). ``own`` gives a cleaner credit signal while the env, and so
    the agent's inputs and all metrics, stay in the configured reward mode."""

    @property
    def learns(self) -> bool:
        return self.policy == "learn"

    def __post_init__(self):
        if not isinstance(self.policy, str) or not self.policy:
            _fail("policy", self.policy, "'learn', a scripted policy name or a checkpoint path ending in .pt")
        if not self.learns and not self.policy.endswith(".pt"):
            from colorgrid.policies import SCRIPTED
            if self.policy not in SCRIPTED:
                _fail("policy", self.policy, f"'learn', one of {sorted(SCRIPTED)} or a checkpoint path ending in .pt")
        if self.init is not None and not isinstance(self.init, str):
            _fail("init", self.init, "a checkpoint path (a string) or null")
        if self.init is not None and not self.learns:
            _fail("init", self.init, "warm-starting only applies to policy='learn'")
        _check_number("aux_coef", self.aux_coef, "a number in [0, 100]", lambda v: 0.0 <= v <= 100.0)
        if self.train_reward not in ("env", "own"):
            _fail("train_reward", self.train_reward, "'env' (the env's reward) or 'own' (own block reward)")
        _check_number("lr", self.lr, "a number in (0, 1), or null to use ppo.lr", lambda v: 0.0 < v < 1.0,
                      optional=True)


@dataclass(frozen=True)
class PPOConfig:
    """PPO settings; defaults are the paper's table."""

    lr: float = 1e-4
    num_envs: int = 16
    num_steps: int = 128
    gamma: float = 0.99
    gae_lambda: float = 0.95
    num_minibatches: int = 4
    update_epochs: int = 4
    clip_coef: float = 0.2
    clip_vloss: bool = True
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = 0.01
    norm_adv: bool = True

    def __post_init__(self):
        for name, lo, hi in (("num_envs", 1, 65536), ("num_steps", 1, 65536), ("num_minibatches", 1, 65536),
                             ("update_epochs", 1, 1000)):
            _check_int(name, getattr(self, name), lo, hi)
        if self.num_envs % self.num_minibatches:
            _fail("num_minibatches", self.num_minibatches,
                  f"must divide ppo.num_envs={self.num_envs} (recurrent minibatches are whole envs)")
        _check_number("lr", self.lr, "a number in (0, 1)", lambda v: 0.0 < v < 1.0)
        for name in ("gamma", "gae_lambda"):
            _check_number(name, getattr(self, name), "a number in [0, 1]", lambda v: 0.0 <= v <= 1.0)
        for name in ("clip_coef", "ent_coef", "vf_coef", "max_grad_norm"):
            _check_number(name, getattr(self, name), "a non-negative number", lambda v: v >= 0.0)
        _check_number("target_kl", self.target_kl, "a positive number, or null to never stop early",
                      lambda v: v > 0.0, optional=True)
        for name in ("clip_vloss", "norm_adv"):
            _check_bool(name, getattr(self, name))


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
        for name in ("penalty_start", "penalty_end"):
            _check_int(name, getattr(self, name), 0, optional=True)
        _check_int("shaping_steps", self.shaping_steps, 0, optional=True)
        if (self.penalty_start is None) != (self.penalty_end is None):
            _fail("penalty_end", self.penalty_end, "set both penalty_start and penalty_end, or neither")
        if self.penalty_start is not None and not self.penalty_start <= self.penalty_end:
            _fail("penalty_start", self.penalty_start, f"0 <= penalty_start <= penalty_end={self.penalty_end}")

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
class TrainConfig:
    """One training run."""

    env: EnvConfig = field(default_factory=EnvConfig)
    leader: AgentConfig = field(default_factory=AgentConfig)
    follower: AgentConfig = field(default_factory=AgentConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    total_steps: int = 1_000_000
    """Env steps to train for (iterations x num_envs x num_steps, rounded up to whole iterations)."""
    seed: int = 0
    eval_every: int = 10
    """Evaluate every this many iterations with the evaluation harness (0: never)."""
    eval_episodes: int = 32
    replay_episodes: int = 2
    """Sample episodes saved as replays at each evaluation."""
    save_every: int = 50
    """Write a checkpoint every this many iterations (and always at the end)."""
    device: str = "auto"
    threads: int = 0
    """Torch CPU threads (0: all cores)."""
    keep_freed_memory: bool = False
    """On a CPU, ask glibc's malloc to keep freed memory (``train/memory.py``): large networks (the
    paper's) reuse their ~100 MB activations instead of page-faulting them in every minibatch,
    1.6x faster; the process then keeps its peak memory. On in the ``paper_*`` presets."""

    def __post_init__(self):
        if not any(a.learns for a in self.agents):
            _fail("leader.policy/follower.policy", (self.leader.policy, self.follower.policy),
                  "at least one agent must have policy='learn'")
        if self.device not in DEVICES:
            _fail("device", self.device, f"choose one of {list(DEVICES)}")
        for name, lo in (("total_steps", 1), ("seed", 0), ("eval_every", 0), ("eval_episodes", 1),
                         ("replay_episodes", 0), ("save_every", 1), ("threads", 0)):
            _check_int(name, getattr(self, name), lo)
        _check_bool("keep_freed_memory", self.keep_freed_memory)
        if self.replay_episodes > self.eval_episodes:
            _fail("replay_episodes", self.replay_episodes, f"at most eval_episodes={self.eval_episodes}")
        if self.env.num_agents != len(AGENTS):
            _fail("env", self.env.num_agents, "the trainer handles one leader and one follower")

    @property
    def agents(self) -> tuple[AgentConfig, AgentConfig]:
        return (self.leader, self.follower)

    @property
    def batch_steps(self) -> int:
        return self.ppo.num_envs * self.ppo.num_steps

    @property
    def num_iterations(self) -> int:
        return -(-self.total_steps // self.batch_steps)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["env"] = self.env.to_dict()
        return d

    @classmethod
    def from_dict(cls, data: dict) -> "TrainConfig":
        return from_dict(data)


_SECTIONS = {"leader": AgentConfig, "follower": AgentConfig, "ppo": PPOConfig, "schedule": ScheduleConfig}


def _build(kind, data: dict, where: str):
    if not isinstance(data, dict):
        raise TrainConfigError(f"{where} must be a mapping, got {type(data).__name__}")
    names = {f.name for f in dataclasses.fields(kind)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise TrainConfigError(f"unknown field(s) {unknown} in {where or 'the training config'}; "
                               f"allowed: {sorted(names)}")
    data = dict(data)
    if kind is AgentConfig and "net" in data:
        data["net"] = _build(NetConfig, data["net"], f"{where}.net")
    try:
        return kind(**data)
    except TrainConfigError as err:
        raise err.within(where) from None


def from_dict(data: dict) -> TrainConfig:
    """A TrainConfig from nested plain data (as in preset files); unknown keys are errors."""
    if not isinstance(data, dict):
        raise TrainConfigError(f"a training config must be a mapping, got {type(data).__name__}")
    data = dict(data)
    data.pop("description", None)
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise TrainConfigError(f"unknown field(s) {unknown} in the training config; allowed: {sorted(names)}")
    if "env" in data:
        data["env"] = EnvConfig.from_dict(data["env"])
    for key, kind in _SECTIONS.items():
        if key in data:
            data[key] = _build(kind, data[key], key)
    return TrainConfig(**data)


def merge(base: dict, override: dict) -> dict:
    """Recursively merge plain dicts (override wins)."""
    out = dict(base)
    for key, value in override.items():
        out[key] = merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESETS_DIR.glob("*.json"))


def load_preset(name: str) -> dict:
    """A preset's plain data by name (``train/presets/<name>.json``) or by file path."""
    path = Path(name)
    if not path.suffix:
        path = PRESETS_DIR / f"{name}.json"
    if not path.exists():
        raise TrainConfigError(f"unknown preset {name!r}: no file {path}; presets: {preset_names()}")
    try:
        return read_json_object(path, "a JSON object of training settings")
    except JSONFileError as err:
        raise TrainConfigError(f"preset {err}") from None


def parse_override(text: str) -> dict:
    """``a.b.c=value`` to ``{"a": {"b": {"c": value}}}``; the value is JSON if it parses, else a string."""
    if "=" not in text:
        raise TrainConfigError(f"--set {text!r}: expected KEY=VALUE, e.g. ppo.lr=3e-4 or follower.net.lstm=true")
    key, raw = text.split("=", 1)
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    out: dict = value
    for part in reversed(key.strip().split(".")):
        out = {part: out}
    return out
