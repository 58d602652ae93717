"""Scripted agents: random, idle, the A* leader, the copy follower and the oracle follower.

Every scripted agent treats every other agent of the team as an obstacle. In a team with several
leaders, the A* leaders share out the goal blocks (``Seeker.claims``); the copy follower copies the
last paying pickup of any leader.
"""

from __future__ import annotations

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.enums import Role
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.card import Part, PolicyCard
from colorgrid.policies.grid import INF, Mover, allowed_cells, decode, distance_field
from colorgrid.policies.registry import scripted
from colorgrid.policies.rewards import explains_reward
from colorgrid.roles import others


@scripted(PolicyCard(lead=Part("Random leader", "moves at random and collects whatever it steps on"),
                     follow=Part("Random mover", "moves at random and collects whatever it steps on"), menu=110))
class RandomPolicy(Policy):
    """Uniformly random actions (seeded)."""

    name = "random"

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        self.rng = np.random.default_rng([seed, agent_index])

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        return PolicyOutput(self.rng.integers(0, self.config.num_actions, inp.observation.shape[0]))


class Seeker(Policy):
    """Shared machinery: walk a shortest path to blocks of wanted colors, around the rest and every other agent."""

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        self.other_indices = others(config, agent_index)
        self.mover = Mover(config, agent_index)
        self.allowed = allowed_cells(config, agent_index)
        self.rng = np.random.default_rng([seed, agent_index, 7])
        # the leaders before this one, if it is a leader: whose blocks it leaves alone (``claims``); an agent in
        # a follower's seat (an A* follower in the symmetric setting) respects no claims
        is_leader = config.roles[agent_index] == Role.LEADER
        self.claimants = [j for j in config.leaders if j < agent_index] if is_leader else []
        self.claimant_movers = [Mover(config, j) for j in self.claimants]
        self.claimant_cells = [allowed_cells(config, j) for j in self.claimants]

    def positions(self, inp: AgentInput):
        """``block_color [B, H, W]``, this agent's cell ``[B]`` and the other agents' cells ``[B, A - 1]``."""
        block_color, agent_cell = decode(inp.observation, self.config)
        return block_color, agent_cell[:, self.agent_index], agent_cell[:, self.other_indices]

    def cells(self, wanted: np.ndarray, block_color: np.ndarray, other: np.ndarray, allowed: np.ndarray | None = None):
        """``[B, H, W]`` masks: blocks of a wanted color, cells this agent may enter (its half, not another
        agent's cell), and those of them without an unwanted block. ``other``: ``[B, K]`` the other agents'
        cells (``[B]``: one)."""
        B, H, W = block_color.shape
        has_block = block_color >= 0
        is_wanted = has_block & np.take_along_axis(wanted, np.maximum(block_color, 0).reshape(B, -1), axis=1
                                                   ).reshape(B, H, W)
        other = other.reshape(B, -1)
        other_mask = np.zeros((B, H * W), dtype=bool)
        other_mask[np.arange(B)[:, None], other] = True
        open_cells = (self.allowed if allowed is None else allowed)[None] & ~other_mask.reshape(B, H, W)
        return is_wanted, open_cells, open_cells & ~(has_block & ~is_wanted)

    def field(self, targets: np.ndarray, open_cells: np.ndarray, clean: np.ndarray, me: np.ndarray,
              avoid_unwanted: bool = True, claimed: np.ndarray | None = None) -> np.ndarray:
        """``[B, H, W]`` distances to the nearest of ``targets``: over ``clean`` cells (around unwanted blocks)
        where a path from ``me`` exists that way, else over every ``open_cells`` cell. With ``claimed``
        (blocks other agents go for), to the nearest unclaimed target where one can be reached, else to any."""
        if claimed is not None:
            dist = self.field(targets & ~claimed, open_cells, clean, me, avoid_unwanted)
            lost = at(dist, me) >= INF
            if lost.any():
                dist[lost] = self.field(targets[lost], open_cells[lost], clean[lost], me[lost], avoid_unwanted)
            return dist
        dist = distance_field(targets, clean if avoid_unwanted else open_cells, start_cell=me)
        if avoid_unwanted:
            lost = at(dist, me) >= INF
            if lost.any():  # no clean path: allow crossing unwanted blocks
                dist[lost] = distance_field(targets[lost], open_cells[lost], start_cell=me[lost])
        return dist

    def seek(self, wanted: np.ndarray, block_color: np.ndarray, me: np.ndarray, other: np.ndarray,
             avoid_unwanted: bool = True, claimed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Actions toward the nearest block whose color is wanted.

        wanted: [B, C] bool; other: [B, K] the other agents' cells. Unwanted blocks and the other agents
        are walls when a path around them exists; otherwise the path may cross unwanted blocks. With
        ``claimed [B, H, W]`` (blocks other agents go for) it heads for the nearest unclaimed wanted block,
        and for any wanted block where it can reach no unclaimed one. Returns ``actions [B]`` and
        ``found [B]`` (a path to a wanted block exists).
        """
        is_wanted, open_cells, clean = self.cells(wanted, block_color, other)
        dist = self.field(is_wanted, open_cells, clean, me, avoid_unwanted, claimed)
        actions, found = self.mover.descend(dist, me, other)
        if not found.all():  # no path at all: wander without collecting
            lost = ~found
            actions[lost] = self.mover.wander(block_color[lost], me[lost], other[lost], self.rng)
        return actions, found

    def claims(self, wanted: np.ndarray, block_color: np.ndarray, agent_cell: np.ndarray) -> np.ndarray | None:
        """``[B, H, W]`` bool: the wanted blocks the leaders before this one go for; None for the first leader
        (and for followers, which claim nothing and respect no claims).

        The rule that shares out blocks between A* leaders: in index order, each leader goes for the
        nearest wanted block (by shortest path, as ``seek`` walks it) that no lower-index leader claimed,
        and claims it: the block its greedy descent leads to. Every leader computes its predecessors'
        claims from the same observation, so the sharing is deterministic and needs no messages (it
        assumes they follow the rule; a leader that does not is still walked around).
        """
        if not self.claimants:
            return None
        B = block_color.shape[0]
        claimed = np.zeros(block_color.shape, dtype=bool)
        for j, mover, allowed in zip(self.claimants, self.claimant_movers, self.claimant_cells):
            me, other = agent_cell[:, j], agent_cell[:, others(self.config, j)]
            is_wanted, open_cells, clean = self.cells(wanted, block_color, other, allowed)
            unclaimed_only = claimed if claimed.any() else None  # nothing claimed yet: one search, not two
            target = mover.destination(self.field(is_wanted, open_cells, clean, me, claimed=unclaimed_only), me,
                                       other)
            going = target >= 0
            claimed.reshape(B, -1)[np.nonzero(going)[0], target[going]] = True
        return claimed


def at(dist: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """``[B]``: the value of ``dist [B, H, W]`` at each env's cell ``cells [B]``."""
    return dist.reshape(len(cells), -1)[np.arange(len(cells)), cells]


@scripted(PolicyCard(lead=Part("Scripted leader (A*)", "knows the goal and walks to the nearest block of it by A*")))
class AStarLeader(Seeker):
    """The paper's leader baseline: knows the goal, walks a shortest path to the nearest goal block.

    With several leaders, each goes for the nearest goal block no lower-index leader claimed
    (``Seeker.claims``), so that two leaders do not chase the same block.
    """

    name = "astar"

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        block_color, agent_cell = decode(inp.observation, self.config)
        me, other = agent_cell[:, self.agent_index], agent_cell[:, self.other_indices]
        wanted = inp.goal_info > 0.5
        if not wanted.any(axis=1).all():
            raise ValueError("the A* policy needs the goal: use it as the leader or with asymmetric=False")
        claimed = self.claims(wanted, block_color, agent_cell)
        actions, _ = self.seek(wanted, block_color, me, other, claimed=claimed)
        return PolicyOutput(actions)


@scripted(PolicyCard(follow=Part("Oracle", "sees the goal: for researchers"),
                     summary="knows the true goal (upper bound)", menu=90))
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


@scripted(PolicyCard(lead=Part("Bystander leader", "walks about and never collects"),
                     follow=Part("Bystander", "walks about and never collects: you play alone"), menu=100))
class IdleFollower(Seeker):
    """Moves to free neighbouring cells and never collects: the leaders, in effect, play without it."""

    name = "idle"

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        block_color, me, other = self.positions(inp)
        return PolicyOutput(self.mover.wander(block_color, me, other, self.rng))


@scripted(PolicyCard(follow=Part("Copycat", "collects the color of the last block you took that paid"),
                     summary="copies the color of the leader's last paying pickup", menu=80))
class CopyFollower(Seeker):
    """The paper's A* follower as its text describes it, for any number of leaders.

    It does not know the goal. Until a leader collects a block that pays, it moves to free
    neighbouring cells without collecting. From then on it walks by A* to the color of the last
    block a leader collected that paid.

    A leader's pickup *pays* when the reward seen in that step is positive and, in ``shared`` mode,
    that color taken as the goal explains the reward: the team reward is the sum over every agent
    that collected in the step, so "positive" alone does not say whose block paid (two leaders
    collecting red and green beside a follower collecting red earn +1 if red is the goal, -1 if
    green is). With one leader this is simply "the leader collected and the reward was positive".
    When several leaders' pickups pay in one step (possible only when their colors explain the
    reward equally, e.g. with no penalty), the last in agent order (the highest index) is copied,
    as pickups resolve in that order. It needs the shared reward: in ``individual`` mode it sees
    only its own reward, and a pickup "pays" only when its own collection in the same step did.
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
        positive = (inp.prev_reward > 0) & ~inp.episode_start
        shared = self.config.reward_mode == "shared"
        explained = explains_reward(inp.prev_picked_color, inp.prev_reward, self.config, inp.penalty_coef,
                                    self.agent_index) if shared else None  # [B, C]
        for leader in self.config.leaders:  # in agent order: the last paying pickup wins
            color = inp.prev_picked_color[:, leader]
            paid = (color >= 0) & positive
            if shared:
                paid[paid] = explained[paid, color[paid]]
            target[paid] = color[paid]
        self.target[rows] = target
        block_color, me, other = self.positions(inp)
        actions = self.mover.wander(block_color, me, other, self.rng)
        active = target >= 0
        if active.any():
            wanted = np.eye(self.config.num_colors, dtype=bool)[target[active]]
            actions[active], _ = self.seek(wanted, block_color[active], me[active], other[active])
        return PolicyOutput(actions)
