"""A follower that infers the leaders' goal with a hidden Markov model and acts on its belief."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.configkit import ConfigBase, check_int, check_number
from colorgrid.policies.base import AgentInput, PolicyOutput
from colorgrid.policies.card import Part, PolicyCard
from colorgrid.policies.grid import decode, manhattan_to_nearest
from colorgrid.policies.registry import scripted
from colorgrid.policies.rewards import explains_reward
from colorgrid.policies.scripted import Seeker


@dataclass(frozen=True)
class BayesConfig(ConfigBase):
    """Parameters of the Bayesian follower's leader model and decision rule."""

    rationality: float = 2.0
    """Boltzmann rationality beta: a leader move that shortens the Manhattan distance to the
    nearest block of color k by delta has weight exp(beta * delta) under goal k. 0 = moves carry
    no information; large = the leader always takes a shortest step."""
    lapse: float = 0.1
    """Probability that a move is unrelated to the goal (detours around blocks, human slips)."""
    reward_noise: float = 1e-3
    """Likelihood given to a reward that contradicts a goal hypothesis (guards against mistakes)."""
    collect_threshold: float = 0.7
    """Collect blocks of a color only when its probability is at least this and the expected
    reward is positive (break-even is wrong_penalty / (goal_reward + wrong_penalty))."""
    standby_radius: int = 3
    """While unsure, stay within this Manhattan distance of the leader, on free cells."""
    notice_rate: float = 1.0
    """Leader model for people: the probability, each step, that a leader pursuing another color than the
    goal turns to the goal (1: it always pursues the current goal, as A* does; 0.3: a switch is noticed
    after about two steps). Below 1 the belief is over (goal, color the leader pursues)."""
    distraction: float = 0.0
    """Leader model for people: the probability, each step, that a leader pursuing the goal sets off after
    another color (a wrong pickup in the making). Its moves then say little about the goal, and the
    negative reward of the wrong pickup is evidence against that color."""

    ERROR_STYLE: ClassVar[str] = "BayesConfig.{name} must be {allowed}, got {value!r}"

    def __post_init__(self) -> None:
        for name in ("rationality", "reward_noise"):
            check_number(self, name, ">= 0", lambda v: v >= 0)
        for name in ("lapse", "collect_threshold", "notice_rate", "distraction"):
            check_number(self, name, "in [0, 1]", lambda v: 0 <= v <= 1)
        check_int(self, "standby_radius", 0, 64)


def transition(belief: np.ndarray, switch_prob: float) -> np.ndarray:
    """[B, C] -> [B, C]: one step of the goal's Markov chain (switch to another color uniformly)."""
    C = belief.shape[1]
    return (1 - switch_prob) * belief + switch_prob * (1 - belief) / (C - 1)


def normalized(post: np.ndarray, prior: np.ndarray, axis) -> np.ndarray:
    """``post`` scaled to sum to 1 over ``axis``; where evidence ruled out every hypothesis (all zero, e.g. a
    leader model with no lapse beside a leader that slipped) the ``prior`` is kept instead of dividing by 0."""
    total = post.sum(axis=axis, keepdims=True)
    return np.where(total > 0, post / np.where(total > 0, total, 1.0), prior)


def goal_transition(joint: np.ndarray, switch_prob: float) -> np.ndarray:
    """[B, C, C] -> [B, C, C]: ``transition`` of the goal (middle axis) of a joint belief over (goal, pursued)."""
    C = joint.shape[1]
    return (1 - switch_prob) * joint + switch_prob * (joint.sum(axis=1, keepdims=True) - joint) / (C - 1)


def leader_transition(joint: np.ndarray, notice_rate: float, distraction: float) -> np.ndarray:
    """[B, C, C] -> [B, C, C]: one step of the color the leader pursues (last axis) given the goal (middle).

    A leader pursuing the goal sets off after each other color with probability distraction / (C - 1);
    one pursuing another color turns to the goal with probability notice_rate.
    """
    C = joint.shape[1]
    on_goal = np.eye(C, dtype=bool)[None]  # [1, G, P]: P == G
    mass_on_goal = np.where(on_goal, joint, 0.0).sum(axis=2, keepdims=True)  # [B, G, 1]
    mass_off_goal = np.where(on_goal, 0.0, joint).sum(axis=2, keepdims=True)
    stay_off = np.where(on_goal, 0.0, joint) * (1 - notice_rate)
    wander = np.where(on_goal, 0.0, mass_on_goal * distraction / (C - 1))
    to_goal = np.where(on_goal, mass_on_goal * (1 - distraction) + mass_off_goal * notice_rate, 0.0)
    return stay_off + wander + to_goal


def move_likelihood(dist_before: np.ndarray, dist_after: np.ndarray, observed: np.ndarray,
                    rationality: float, lapse: float) -> np.ndarray:
    """[B, C]: probability of the leader's observed move under each goal color.

    dist_before: [B, C] distance from the leader's old cell to the nearest block of each color;
    dist_after: [B, M, C] the same from the cell each of the M actions leads to;
    observed: [B, M] bool, actions consistent with the leader's new cell.
    """
    logits = rationality * (dist_before[:, None, :] - dist_after)  # [B, M, C]
    logits -= logits.max(axis=1, keepdims=True)
    pi = np.exp(logits)
    pi /= pi.sum(axis=1, keepdims=True)
    M = dist_after.shape[1]
    p = (pi * observed[:, :, None]).sum(axis=1)
    return (1 - lapse) * p + lapse * observed.sum(axis=1, keepdims=True) / M


def reward_likelihood(picked: np.ndarray, reward: np.ndarray, config: EnvConfig, penalty_coef: float,
                      agent_index: int, noise: float) -> np.ndarray:
    """[B, C]: probability of the observed reward under each goal color.

    picked: [B, A] colors collected last step (-1 none); reward: [B] this agent's unshaped reward.
    In shared mode the reward is the team's, the sum over every agent that collected (each pickup
    adds ``goal_reward`` under a goal of its color, ``-wrong_penalty * penalty_coef`` under any other),
    so the likelihood is exact however many agents collected; in individual mode it covers only the
    agent's own pickup. A goal that predicts another reward gets ``noise``.
    """
    explained = explains_reward(picked, reward, config, penalty_coef, agent_index)
    return np.where(explained, 1.0, noise)


PEOPLE = BayesConfig(rationality=2.0, lapse=0.1, notice_rate=0.5, distraction=0.01)
"""The leader model of ``bayes-people``: a leader that notices a goal switch after about a step and sets off
after a wrong block now and then. Chosen among four candidates on the training part of
``populations/people.json`` (docs/EVALUATION.md), never on the held-out part."""


@scripted(PolicyCard(follow=Part("Bayesian assistant",
                                  "works out the goal from your moves and pickups, and collects once it is sure"),
                     belief=True, summary="infers the goal with a hidden Markov model", menu=70))
class BayesFollower(Seeker):
    """Keeps a posterior over the goal color and collects only when it is confident.

    Hidden Markov model: uniform prior at the episode start; the goal's transition is
    the env's ``switch_prob``; evidence each step is (a) every leader's move, scored by a
    Boltzmann-rational model of how much it shortened that leader's distance to the
    nearest block of each color (the leaders move independently given what they pursue,
    so their likelihoods multiply), and (b) the blocks every agent collected, with the
    reward observed (``reward_likelihood``). ``goal_probs`` is the belief over the *current* goal.

    With the people model (``notice_rate < 1`` or ``distraction > 0``) each leader pursues a color of
    its own; the belief is kept as one ``[goal, pursued]`` table per leader (``joint [B, L, C, C]``),
    all with the same goal marginal. A leader's move weighs each goal by its likelihood averaged over
    what that leader may pursue under the goal; every table then conditions on the goal posterior.
    This treats the leaders' pursued colors as independent given the current goal: exact for one
    leader, an approximation after a goal switch for several (their late turns are correlated
    through the goal they all saw before).
    """

    name = "bayes"
    Params = BayesConfig
    state_fields = ("belief", "joint", "prev_blocks", "prev_cells", "has_prev")

    def __init__(self, params: BayesConfig | None = None):
        self.params = params or BayesConfig()

    def describe(self) -> dict:
        from dataclasses import asdict

        return {"policy": self.name, "params": asdict(self.params)}

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        C, L = config.num_colors, config.num_leaders
        self.belief = np.full((num_envs, C), 1.0 / C)
        self.joint = np.broadcast_to(np.eye(C) / C, (num_envs, L, C, C)).copy()  # [B, leader, goal, pursued]
        self.prev_blocks = np.full((num_envs, config.height, config.width), -1, dtype=np.int8)
        self.prev_cells = np.zeros((num_envs, config.num_agents), dtype=np.int64)
        self.has_prev = np.zeros(num_envs, dtype=bool)
        from colorgrid.env import move_table

        self.leader_tables = move_table(config)[list(config.leaders)]  # [L, H*W, M]: the leaders show the goal

    def load_state_dict(self, state: dict) -> None:
        """As ``Policy.load_state_dict``; a 1:1 state saved before teams (``joint [B, C, C]``) loads as one leader's."""
        joint = np.asarray(state.get("joint"))
        if joint.ndim == 3 and self.config.num_leaders == 1:
            state = {**state, "joint": joint[:, None]}
        super().load_state_dict(state)

    def update(self, inp: AgentInput, rows: np.ndarray, block_color: np.ndarray, agent_cell: np.ndarray) -> np.ndarray:
        """Fold last step's evidence into the belief of ``rows`` and advance it to the current goal."""
        cfg = self.config
        C, L = cfg.num_colors, cfg.num_leaders
        belief, joint = self.belief[rows], self.joint[rows]
        fresh = inp.episode_start | ~self.has_prev[rows]
        go = ~fresh
        if go.any():
            move, reward = self._evidence(inp, rows[go], go, block_color, agent_cell)  # [n, L, C], [n, C]
            n = move.shape[0]
            if self.params.notice_rate == 1.0 and self.params.distraction == 0.0:  # the leaders pursue the goal
                likelihood = move[:, 0]
                for leader in range(1, L):
                    likelihood = likelihood * move[:, leader]
                post = belief[go] * likelihood * reward
                post = normalized(post, belief[go], axis=1)
                belief[go] = transition(post, cfg.switch_prob)
                joint[go] = (belief[go][:, :, None] * np.eye(C)[None])[:, None]
            else:  # moves show the colors pursued, rewards the goal
                prior = joint[go]  # [n, L, goal, pursued]
                goal_evidence = reward[:, None, :] * _other_leaders(prior, move)  # [n, L, goal]
                post = prior * goal_evidence[..., None] * move[:, :, None, :]
                post = normalized(post.reshape(n * L, C, C), prior.reshape(n * L, C, C), axis=(1, 2))
                post = leader_transition(goal_transition(post, cfg.switch_prob), self.params.notice_rate,
                                         self.params.distraction)
                joint[go] = post.reshape(n, L, C, C)
                belief[go] = joint[go][:, 0].sum(axis=2)
        belief[fresh] = 1.0 / C
        joint[fresh] = np.eye(C)[None, None] / C
        self.belief[rows], self.joint[rows] = belief, joint
        self.prev_blocks[rows] = block_color
        self.prev_cells[rows] = agent_cell
        self.has_prev[rows] = True
        return belief

    def _evidence(self, inp: AgentInput, slots: np.ndarray, mask: np.ndarray, block_color, agent_cell):
        """``[n, L, C]`` likelihoods of each leader's move last step (under each color it may pursue) and ``[n, C]``
        of the reward (under each goal), for the inputs selected by ``mask``.

        A leader's possible moves are those of the rules: moves resolve in agent order, so leader ``j`` was
        blocked by the new cells of the agents before it and the old cells of those after it.
        """
        cfg, p = self.config, self.params
        L, A = cfg.num_leaders, cfg.num_agents
        before = self.prev_cells[slots]  # [n, A]
        after = agent_cell[mask]  # [n, A]
        cells, observed = [], []
        for leader in cfg.leaders:
            blockers = np.concatenate([after[:, :leader], before[:, leader + 1:A]], axis=1)  # [n, A - 1]
            start = before[:, leader]
            table = self.leader_tables[leader][start]  # [n, M] cells each of its actions leads to
            blocked = (table[:, :, None] == blockers[:, None, :]).any(axis=2)
            table = np.where(blocked, start[:, None], table)
            observed.append(table == after[:, leader][:, None])
            cells.append(np.concatenate([start[:, None], table], axis=1))
        n, M = len(slots), observed[0].shape[1]
        d = manhattan_to_nearest(cfg, self.prev_blocks[slots].astype(np.int64), np.concatenate(cells, axis=1))
        d = d.reshape(n * L, 1 + M, cfg.num_colors)  # [n * L, 1 + M, C]
        move = move_likelihood(d[:, 0], d[:, 1:], np.stack(observed, axis=1).reshape(n * L, M), p.rationality,
                               p.lapse).reshape(n, L, cfg.num_colors)
        reward = reward_likelihood(inp.prev_picked_color[mask], inp.prev_reward[mask], cfg, inp.penalty_coef,
                                   self.agent_index, p.reward_noise)
        return move, reward

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        cfg, p = self.config, self.params
        rows = self._rows(rows)
        block_color, agent_cell = decode(inp.observation, cfg)
        belief = self.update(inp, rows, block_color, agent_cell)
        me, other = agent_cell[:, self.agent_index], agent_cell[:, self.other_indices]
        expected = belief * cfg.goal_reward - (1 - belief) * cfg.wrong_penalty * inp.penalty_coef
        wanted = (belief >= p.collect_threshold) & (expected > 0)
        sure = wanted.any(axis=1)
        actions = self.standby(block_color, me, other, nearest_leader(agent_cell, me, cfg))
        if sure.any():
            actions[sure], _ = self.seek(wanted[sure], block_color[sure], me[sure], other[sure])
        return PolicyOutput(actions, belief.astype(np.float32))

    def standby(self, block_color: np.ndarray, me: np.ndarray, other: np.ndarray, leader: np.ndarray) -> np.ndarray:
        """Stay near a leader without collecting: step toward it over free cells if far, else wander.

        other: [B, K] every other agent's cell (obstacles); leader: [B] the cell of the leader to stay near.
        """
        B = block_color.shape[0]
        W = self.config.width
        actions = self.mover.wander(block_color, me, other, self.rng)
        nxt, moves = self.mover.neighbours(me, other)  # [B, 4]
        free = moves & (block_color.reshape(B, -1)[np.arange(B)[:, None], nxt] < 0)
        lr, lc = np.divmod(leader, W)
        nr, nc = np.divmod(nxt, W)
        gap = np.abs(nr - lr[:, None]) + np.abs(nc - lc[:, None])  # [B, 4] distance after each move
        mr, mc = np.divmod(me, W)
        now = np.abs(mr - lr) + np.abs(mc - lc)
        gap = np.where(free, gap, 1 << 20)
        closer = (now > self.params.standby_radius) & (gap.min(axis=1) < now)
        actions[closer] = gap[closer].argmin(axis=1)
        return actions


def nearest_leader(agent_cell: np.ndarray, me: np.ndarray, config: EnvConfig) -> np.ndarray:
    """``[B]``: the cell of the leader nearest to ``me [B]`` (Manhattan; ties to the lower index)."""
    leaders = agent_cell[:, list(config.leaders)]  # [B, L]
    lr, lc = np.divmod(leaders, config.width)
    mr, mc = np.divmod(me, config.width)
    gap = np.abs(lr - mr[:, None]) + np.abs(lc - mc[:, None])
    return leaders[np.arange(len(me)), gap.argmin(axis=1)]


def _other_leaders(joint: np.ndarray, move: np.ndarray) -> np.ndarray:
    """``[n, L, C]``: for each leader, the product over the *other* leaders of their move's likelihood under
    each goal, averaged over the color each may pursue given the goal (``joint [n, L, goal, pursued]``,
    ``move [n, L, pursued]``). All ones for a single leader."""
    n, L, C, _ = joint.shape
    out = np.ones((n, L, C))
    if L == 1:
        return out
    marginal = joint.sum(axis=3)  # [n, L, goal]
    weighted = (joint * move[:, :, None, :]).sum(axis=3)
    per_goal = np.divide(weighted, marginal, out=np.zeros_like(weighted), where=marginal > 0)  # [n, L, goal]
    for leader in range(L):
        for other in range(L):
            if other != leader:
                out[:, leader] *= per_goal[:, other]
    return out


@scripted(PolicyCard(follow=Part("Bayesian assistant for people",
                                  ("the Bayesian assistant, forgiving of late turns and slips, so a wrong move is not "
                                   "taken for a goal switch")),
                     belief=True, menu=10))
class PeopleBayesFollower(BayesFollower):
    """The Bayesian follower with a leader model for people (``PEOPLE``): a belief over the goal and the color
    the leader pursues, so that a slip, a late turn or a wrong pickup is not taken for a goal switch."""

    name = "bayes-people"
    default_params = PEOPLE

    def __init__(self, params: BayesConfig | None = None):
        super().__init__(params or PEOPLE)
