"""A follower that moves by one policy and reads the goal by another: a trained network kept off the blocks a model
of people doubts.

``shielded:mover=ippo-people,reader=bayes-people,min_belief=0.8`` moves as ``mover`` (a policy that samples its
moves: a trained network) would, except onto a block whose color the ``reader``'s belief (``PolicyOutput.goal_probs``:
the Bayesian follower's posterior) gives less than ``min_belief``; those moves are taken out before the mover samples,
unless every move is one (``colorgrid.policies.grid.unsure_moves``). It is a shield in the sense of safe
reinforcement learning (Alshiekh et al. 2018): the learned policy keeps its way of collecting, the model of the
person decides which colors are safe to collect. Its belief is the reader's.

The reader also plays every step (its own action is not used), so its belief follows the whole game as it would
beside the same leader.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from colorgrid.configkit import fail
from colorgrid.env import ACTION_NAMES, move_table
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.card import Part, PolicyCard
from colorgrid.policies.grid import unsure_moves
from colorgrid.policies.registry import scripted

SHIELD = "shielded"
STAY = ACTION_NAMES.index("stay")


@dataclass(frozen=True)
class ShieldParams:
    """Which policy moves, which one's belief keeps it off doubted blocks, and how sure the belief must be."""

    mover: str = ""
    """A policy that samples its moves (``Policy.avoids_moves``): a trained follower (``ippo-people``, ``x.pt``)."""
    reader: str = "bayes-people"
    """A policy whose belief over the goal the shield reads: a Bayesian follower."""
    min_belief: float = 0.8
    """The least belief in a block's color for the mover to be let onto it."""

    def __post_init__(self) -> None:
        for name in ("mover", "reader"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value or value.partition(":")[0] == SHIELD:
                fail(self, name, "a policy name other than a shielded follower (e.g. 'ippo-people', 'bayes-people')")
        if isinstance(self.min_belief, bool) or not isinstance(self.min_belief, (int, float)) \
                or not 0 <= self.min_belief <= 1:
            fail(self, "min_belief", "a number in [0, 1]")

    def inner(self) -> dict[str, str]:
        """The policies it is built from, by their part in it."""
        return {"mover": self.mover, "reader": self.reader}

    def described(self) -> dict:
        """Its own setting, for replays (the parts describe themselves)."""
        return {"min_belief": self.min_belief}


def shield_card(params: ShieldParams, cards: dict[str, PolicyCard | None]) -> PolicyCard:
    """What a shielded follower says of itself: its mover's label, kept off blocks by its reader, and a yardstick
    when either part is one (``bayes-limit`` as the reader: no person is given it). The teams it plays are its
    parts' (``policy_teams``)."""
    def shown(part: str) -> str:
        card = cards.get(part)
        name = getattr(params, part)
        return card.follow.label if card is not None and card.follow is not None else name

    yardstick = next((c.yardstick for c in cards.values() if c is not None and c.yardstick is not None), None)
    return PolicyCard(follow=Part("Shielded assistant",
                                  f"{shown('mover')}, kept off any block that the {shown('reader')} doubts"),
                      belief=True, yardstick=yardstick,
                      summary=f"{params.mover}'s moves, kept off blocks whose color {params.reader}'s belief gives "
                              f"less than {params.min_belief:g} (colorgrid/policies/shielded.py)")


@scripted(PolicyCard(follow=Part("Shielded assistant", "a trained assistant, kept off any block a Bayesian one doubts"),
                     belief=True, summary="a mover kept off blocks a reader's belief doubts (shielded:mover=...,reader=...)"))
class ShieldedFollower(Policy):
    """``mover``'s moves, kept off the blocks ``reader``'s belief doubts (module docstring). Both keep their own
    memory and random generators, reset with this policy's seed; ``state_dict`` holds both."""

    name = SHIELD
    Params = ShieldParams

    def __init__(self, params: ShieldParams | None = None, mover: Policy | None = None, reader: Policy | None = None):
        if params is None or mover is None or reader is None:
            raise ValueError(f"{SHIELD} needs a mover and a reader: {SHIELD}:mover=NAME,reader=NAME,min_belief=X "
                             f"(built by make_policy)")
        for part, policy in (("mover", mover), ("reader", reader)):
            if isinstance(policy, ShieldedFollower):
                raise ValueError(f"{SHIELD}: {part} {getattr(params, part)!r} is a shielded follower itself; a "
                                 f"shield's parts are a network and a Bayesian follower")
        if not mover.avoids_moves:
            raise ValueError(f"{SHIELD}: mover {params.mover!r} cannot be kept off moves; a trained network can")
        self.params, self.mover, self.reader = params, mover, reader

    @staticmethod
    def card_around(params: ShieldParams, cards: dict[str, PolicyCard | None]) -> PolicyCard:
        """``shield_card``: what a shielded follower says of itself, from its parts' cards."""
        return shield_card(params, cards)

    def describe(self) -> dict:
        return {"policy": self.name, "mover": self.mover.describe(), "reader": self.reader.describe(),
                "params": self.params.described()}

    def reset(self, config, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        self.mover.reset(config, num_envs, agent_index, seed)
        self.reader.reset(config, num_envs, agent_index, seed)
        self.moves = move_table(config)[agent_index]  # [H*W, actions]: the cell each move leads to

    def see_team(self, policies: list[Policy]) -> None:
        self.mover.see_team(policies)
        self.reader.see_team(policies)

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        """The reader's belief; the mover's action with the moves onto doubted blocks taken out. Where the env has
        ``stay`` and the mover could take no other move (a network trained without ``stay``, boxed in by doubted
        blocks), it stays instead."""
        read = self.reader.act(inp, rows)
        if read.goal_probs is None:
            raise ValueError(f"{SHIELD}: reader {self.params.reader!r} forms no belief over the goal")
        avoid = unsure_moves(inp.observation, np.asarray(read.goal_probs), self.moves, self.config,
                             self.agent_index, self.params.min_belief)
        actions = np.asarray(self.mover.act_avoiding(inp, rows, avoid).actions, dtype=np.int64)
        if self.config.allow_stay:
            actions = np.where(avoid[np.arange(len(actions)), actions], STAY, actions)
        return PolicyOutput(actions, read.goal_probs)

    def state_dict(self) -> dict:
        return {"mover": self.mover.state_dict(), "reader": self.reader.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.mover.load_state_dict(state["mover"])
        self.reader.load_state_dict(state["reader"])


__all__ = ["SHIELD", "ShieldParams", "ShieldedFollower", "shield_card"]

