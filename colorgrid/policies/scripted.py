"""Scripted agents: random, idle, the A* leader, the copy follower and the oracle follower."""

from __future__ import annotations

import numpy as np

from colorgrid.config import LEADER, EnvConfig
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.grid import Mover, allowed_cells, decode, distance_field
from colorgrid.roles import partner


class RandomPolicy(Policy):
    """Uniformly random actions (seeded)."""

    name = "random"

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        self.rng = np.random.default_rng([seed, agent_index])

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        return PolicyOutput(self.rng.integers(0, self.config.num_actions, inp.observation.shape[0]))


class Seeker(Policy):
    """Shared machinery: walk a shortest path to blocks of wanted colors, around the rest."""

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        self.partner_index = partner(agent_index)
        self.mover = Mover(config, agent_index)
        self.allowed = allowed_cells(config, agent_index)
        self.rng = np.random.default_rng([seed, agent_index, 7])

    def positions(self, inp: AgentInput):
        block_color, agent_cell = decode(inp.observation, self.config)
        return block_color, agent_cell[:, self.agent_index], agent_cell[:, self.partner_index]

    def cells(self, wanted: np.ndarray, block_color: np.ndarray, other: np.ndarray):
        """``[B, H, W]`` masks: blocks of a wanted color, cells this agent may enter (its half, not the other
        agent's cell), and those of them without an unwanted block."""
        B, H, W = block_color.shape
        has_block = block_color >= 0
        is_wanted = has_block & np.take_along_axis(wanted, np.maximum(block_color, 0).reshape(B, -1), axis=1
                                                   ).reshape(B, H, W)
        other_mask = np.zeros((B, H * W), dtype=bool)
        other_mask[np.arange(B), other] = True
        open_cells = self.allowed[None] & ~other_mask.reshape(B, H, W)
        return is_wanted, open_cells, open_cells & ~(has_block & ~is_wanted)

    def seek(self, wanted: np.ndarray, block_color: np.ndarray, me: np.ndarray, other: np.ndarray,
             avoid_unwanted: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Actions toward the nearest block whose color is wanted.

        wanted: [B, C] bool. Unwanted blocks and the other agent are walls when a path
        around them exists; otherwise the path may cross unwanted blocks. Returns
        ``actions [B]`` and ``found [B]`` (a path to a wanted block exists).
        """
        is_wanted, open_cells, clean = self.cells(wanted, block_color, other)
        passable = clean if avoid_unwanted else open_cells
        dist = distance_field(is_wanted, passable, start_cell=me)
        actions, found = self.mover.descend(dist, me, other)
        if avoid_unwanted and not found.all():  # no clean path: allow crossing unwanted blocks
            lost = ~found
            dist = distance_field(is_wanted[lost], open_cells[lost], start_cell=me[lost])
            actions[lost], found[lost] = self.mover.descend(dist, me[lost], other[lost])
        if not found.all():  # no path at all: wander without collecting
            lost = ~found
            actions[lost] = self.mover.wander(block_color[lost], me[lost], other[lost], self.rng)
        return actions, found


class AStarLeader(Seeker):
    """The paper's leader baseline: knows the goal, walks a shortest path to the nearest goal block."""

    name = "astar"

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        block_color, me, other = self.positions(inp)
        wanted = inp.goal_info > 0.5
        if not wanted.any(axis=1).all():
            raise ValueError("the A* policy needs the goal: use it as the leader or with asymmetric=False")
        actions, _ = self.seek(wanted, block_color, me, other)
        return PolicyOutput(actions)


class OracleFollower(Seeker):
    """A* with the true goal, read from privileged ground truth: an upper bound for followers."""

    name = "oracle"

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        if inp.true_goal is None:
            raise ValueError("the oracle follower needs the true goal (AgentInput.true_goal)")
        block_color, me, other = self.positions(inp)
        wanted = np.eye(self.config.num_colors, dtype=bool)[inp.true_goal]
        actions, _ = self.seek(wanted, block_color, me, other)
        return PolicyOutput(actions, wanted.astype(np.float32))


class IdleFollower(Seeker):
    """Moves to free neighbouring cells and never collects: the leader, in effect, plays alone."""

    name = "idle"

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        block_color, me, other = self.positions(inp)
        return PolicyOutput(self.mover.wander(block_color, me, other, self.rng))


class CopyFollower(Seeker):
    """The paper's A* follower as its text describes it.

    It does not know the goal. Until the leader collects a block that pays (a
    positive reward is observed in the step the leader collected it), it moves to
    free neighbouring cells without collecting. From then on it walks by A* to
    the color of the last block the leader collected that paid. It needs the
    shared reward (in ``individual`` mode it never sees the leader's reward).
    """

    name = "copy"
    state_fields = ("target",)

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        self.target = np.full(num_envs, -1, dtype=np.int64)

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        rows = self._rows(rows)
        target = self.target[rows]
        target[inp.episode_start] = -1
        leader_color = inp.prev_picked_color[:, LEADER]
        paid = (leader_color >= 0) & (inp.prev_reward > 0) & ~inp.episode_start
        target[paid] = leader_color[paid]
        self.target[rows] = target
        block_color, me, other = self.positions(inp)
        actions = self.mover.wander(block_color, me, other, self.rng)
        active = target >= 0
        if active.any():
            wanted = np.eye(self.config.num_colors, dtype=bool)[target[active]]
            actions[active], _ = self.seek(wanted, block_color[active], me[active], other[active])
        return PolicyOutput(actions)
