"""The one interface every agent implements, scripted or learned."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from colorgrid.config import EnvConfig

if TYPE_CHECKING:
    from colorgrid.policies.card import PolicyCard


@dataclass
class AgentInput:
    """What an agent may legitimately observe at one step, for a batch of B envs.

    The previous-step fields describe what everyone sees on the board and in the
    reward signal: which block vanished under which agent, and the reward this
    agent received (the team reward in ``shared`` mode).
    """

    observation: np.ndarray  # [B, P, H, W] uint8 planes (colors, then one per agent in index order)
    goal_info: np.ndarray  # [B, C] float32 one-hot goal, zeros if hidden from this agent
    episode_start: np.ndarray  # [B] bool: first step of an episode (reset internal state)
    prev_reward: np.ndarray  # [B] float32: this agent's unshaped block reward last step (0 at start)
    prev_picked_color: np.ndarray  # [B, A] int64: color collected by each agent last step, -1 if none
    prev_actions: np.ndarray  # [B, A] int64: every agent's last action, -1 at start
    penalty_coef: float = 1.0  # the env's current penalty coefficient
    true_goal: np.ndarray | None = None  # [B] privileged ground truth; only the oracle reads it

    def select(self, rows) -> "AgentInput":
        """The input of the envs ``rows`` only."""
        def take(name):
            value = getattr(self, name)
            return None if value is None else value[rows]

        return AgentInput(**{f: take(f) for f in _BATCHED}, penalty_coef=self.penalty_coef)

    @classmethod
    def concat(cls, inputs: list["AgentInput"]) -> "AgentInput":
        """Inputs of several batches as one, along the batch axis (their ``penalty_coef`` is the first's)."""
        def cat(name):
            values = [getattr(i, name) for i in inputs]
            return None if values[0] is None else np.concatenate(values)

        return cls(**{f: cat(f) for f in _BATCHED}, penalty_coef=inputs[0].penalty_coef)


_BATCHED = ("observation", "goal_info", "episode_start", "prev_reward", "prev_picked_color", "prev_actions",
            "true_goal")


@dataclass
class PolicyOutput:
    actions: np.ndarray  # [B] int64
    goal_probs: np.ndarray | None = None  # [B, C] float: the agent's belief over the goal, or None


class Policy:
    """Base class: ``reset`` once for a batch, then ``act`` every step.

    Subclasses keep any memory (beliefs, LSTM state) as batched arrays and clear
    the rows flagged by ``episode_start``. ``act(inp, rows)`` may be given inputs
    for a subset of the batch: ``rows`` are their indices (all rows when None).
    This lets one policy serve many independent games (the play server).
    """

    name = "policy"
    state_fields: tuple[str, ...] = ()
    """Array attributes that change while acting (beliefs, targets): what ``state_dict`` saves besides ``rng``."""

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        self.config = config
        self.num_envs = num_envs
        self.agent_index = agent_index
        self.seed = seed

    def act(self, inp: AgentInput, rows: np.ndarray | None = None) -> PolicyOutput:
        raise NotImplementedError

    def act_avoiding(self, inp: AgentInput, rows: np.ndarray | None, avoid: np.ndarray | None) -> PolicyOutput:
        """``act``, never taking a move that ``avoid`` (``[B, actions]`` bool: the env's actions, in its order)
        marks, unless it marks every move of a row. Only a policy that samples its moves can (``avoids_moves``: a
        trained network); the others raise ``TypeError``."""
        raise TypeError(f"{self.name} cannot be kept off moves (a trained network, which samples its moves, can)")

    avoids_moves = False
    """Whether ``act_avoiding`` can keep it off moves."""

    @staticmethod
    def card_around(params, cards: dict) -> PolicyCard:
        """What a policy built around others says of itself, from its parts' cards (``cards``: part -> card, by the
        names its ``params.inner()`` gives; ``colorgrid.policies.inner_policies``). Only a scripted policy whose
        ``Params`` has ``inner`` is asked; it must then say."""
        raise NotImplementedError("a policy whose parameters name other policies (Params.inner) must say what it "
                                  "is through their cards (card_around)")

    def see_team(self, policies: "list[Policy]") -> None:
        """Told, after every ``reset`` of an evaluation, the policy of every agent (index order). Privileged, as
        ``AgentInput.true_goal`` is: only a policy that stands for a bound reads it (``bayes-limit``, given its
        leader's true model); the rest ignore it."""

    def _rows(self, rows: np.ndarray | None) -> np.ndarray:
        return np.arange(self.num_envs) if rows is None else np.asarray(rows)

    def describe(self) -> dict:
        """How replays and reports name this agent."""
        return {"policy": self.name}

    def describe_row(self, row: int) -> dict:
        """How the replay of the game in batch row ``row`` names this agent: ``describe()``, and where the policy plays
        by parts, the part that game had (a population: the member drawn for it)."""
        return self.describe()

    def state_dict(self) -> dict:
        """What changes while acting, as arrays and plain values, so that a resumed run continues exactly:
        the ``state_fields`` and the random generator's state (``rng``) if the policy has one."""
        out = {name: np.array(getattr(self, name)) for name in self.state_fields}
        if hasattr(self, "rng"):
            out["rng"] = self.rng.bit_generator.state
        return out

    def load_state_dict(self, state: dict) -> None:
        """Restore what ``state_dict`` saved, on a policy ``reset`` with the same config and batch size."""
        for name in self.state_fields:
            current = getattr(self, name)
            value = np.asarray(state[name], dtype=current.dtype)
            if value.shape != current.shape:
                raise ValueError(f"{self.name}: saved {name} has shape {value.shape}, expected {current.shape}")
            setattr(self, name, value.copy())
        if "rng" in state:
            self.rng.bit_generator.state = state["rng"]
