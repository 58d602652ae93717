"""The information limit: a Bayesian follower given its leader's true model (``bayes-limit``).

``bayes`` and ``bayes-people`` read the leader through a model of their own (a Boltzmann-rational walker with
a lapse; ``bayes-people`` adds late turns and distraction). ``bayes-limit`` is given the model the leader
really follows: the parameters of its ``PersonStyle`` (the A* leader is the style with every departure
off), and beside a population those of the member drawn for each episode. It then filters exactly: its
belief is over the goal and everything the leader keeps in mind (the color it pursues, the steps before it
notices a switch, a wrong color it set off after, the steps and direction of a detour), and each step it
weighs the leader's observed action by the probability the leader's own rules give it (the A* step or
the Boltzmann move toward each color it may pursue, hesitation, slips, detours), and the reward by the goal
it implies. What it believes is therefore the posterior over the goal given everything it has seen: no
follower that reads the same history names the goal more accurately on average, nor with a lower expected
log-loss. It is the limit of reading the leader, not of every way to learn the goal (a follower that acted
otherwise would see other things: a block it collects tells it whether that color pays). It acts on that
belief by ``bayes``'s rule (``BayesConfig``'s threshold and standby), so its pickups are those of the best
belief under one decision rule, not a bound on pickups.

Being told the leader's model is privileged, as the oracle's true goal is: the evaluation harness tells it
(``Policy.see_team``, called by ``colorgrid.rollout.run_team``: ``colorgrid eval`` and its ``--leaders``
matrix). It needs one leader whose model it can be given: ``astar``, ``person:...`` or a population of them.

The joint belief, per env, has the axes ``[goal, target, pending, distracted, detour]``: the goal at the
leader's next step; the goal the leader pursues when not distracted; the steps left before it notices that
the goal differs from its target (index 0: none pending, ``1 + k``: ``k`` more steps); the wrong color it
set off after (index ``C``: none); the detour it is on (index 0: none, ``1 + 4 (left - 1) + direction``).
"""

from __future__ import annotations

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.policies.base import AgentInput, Policy
from colorgrid.policies.bayes import BayesConfig, BayesFollower, reward_likelihood
from colorgrid.policies.card import PolicyCard
from colorgrid.policies.people import PersonLeader, PersonStyle
from colorgrid.policies.registry import scripted
from colorgrid.policies.scripted import AStarLeader
from colorgrid.policies.styled import StyledLeader

MOVES = 4
"""A person-like leader's actions: the four moves (it never stays)."""


def notice_table(style: PersonStyle, num_colors: int) -> np.ndarray:
    """``[goal, target, pending, target', pending']``: the leader's late noticing as a transition (its ``act``).

    A target that differs from the goal with none pending starts a delay (``notice_delay``, or drawn uniformly up
    to ``notice_delay_max``); each step then counts it down, and the leader turns to the goal when it runs out.
    A goal that switched back to the target ends what was pending.
    """
    C = num_colors
    low = style.notice_delay
    high = style.notice_delay if style.notice_delay_max is None else style.notice_delay_max
    R = 1 + high
    table = np.zeros((C, C, R, C, R))
    for goal in range(C):
        for target in range(C):
            if target == goal:
                table[goal, target, :, target, 0] = 1.0
                continue
            for delay in range(low, high + 1):  # a fresh difference: the delay of this switch
                if delay == 0:
                    table[goal, target, 0, goal, 0] += 1.0 / (high - low + 1)
                else:
                    table[goal, target, 0, target, delay] += 1.0 / (high - low + 1)
            if R > 1:
                table[goal, target, 1, goal, 0] = 1.0  # the last step of a delay: it notices
            for pending in range(2, R):
                table[goal, target, pending, target, pending - 1] = 1.0
    return table


def detour_states(style: PersonStyle) -> int:
    """The size of the detour axis: none, or ``(steps left 1..detour_len - 1) x direction``."""
    return 1 + (MOVES * (style.detour_len - 1) if style.detour > 0 else 0)


def initial_joint(num_envs: int, style: PersonStyle, num_colors: int) -> np.ndarray:
    """``[B, goal, target, pending, distracted, detour]`` at an episode start: a uniform goal, pursued as is."""
    C = num_colors
    R = notice_table(style, C).shape[2]
    joint = np.zeros((num_envs, C, C, R, C + 1, detour_states(style)))
    joint[:, np.arange(C), np.arange(C), 0, C, 0] = 1.0 / C
    return joint


def leader_step(joint: np.ndarray, move_probs: np.ndarray, action: np.ndarray, last: np.ndarray,
                picked_before: np.ndarray, style: PersonStyle) -> np.ndarray:
    """One step of the leader's ``act``, weighed by the action it took: the unnormalised joint after the step.

    joint: ``[B, goal, target, pending, distracted, detour]`` before the step, its goal the one the leader saw;
    move_probs: ``[B, C, 4]`` the probability of each move under each color pursued (the A* step or Boltzmann
    moves, from the board the leader saw); action: ``[B]`` the move it made; last: ``[B]`` the move before (-1 at
    the start: no hesitation); picked_before: ``[B]`` bool, it collected a block the step before (which ends a
    distraction).
    """
    B, C = joint.shape[0], joint.shape[1]
    rows = np.arange(B)
    joint = np.einsum("bgtrzq,gtrus->bguszq", joint, notice_table(style, C))
    if picked_before.any():
        ended = joint[picked_before]
        total = ended.sum(axis=4)
        ended[:] = 0.0
        ended[..., C, :] = total
        joint[picked_before] = ended
    if style.wrong_pickup > 0:  # it sets off after one of the other colors than its target
        free = joint[..., C, :].copy()  # [B, goal, target, pending, detour]
        others = (1.0 - np.eye(C))[None, None, :, None, :, None]  # [target, distracted]
        joint[..., :C, :] += style.wrong_pickup / (C - 1) * free[:, :, :, :, None, :] * others
        joint[..., C, :] = (1.0 - style.wrong_pickup) * free
    pursued = np.concatenate([np.tile(np.arange(C), (C, 1)), np.arange(C)[:, None]], axis=1)  # [target, distracted]
    planned = move_probs[rows, :, action][:, pursued]  # [B, target, distracted]: its own plan's chance of the action
    hesitate = np.where(last >= 0, style.hesitate, 0.0)

    def taken(plain: np.ndarray) -> np.ndarray:
        """The chance of the action given the chance ``plain [B, ...]`` of the move it meant: a slip is any move,
        a hesitation repeats the last."""
        extra = (1,) * (plain.ndim - 1)
        return (style.slip / MOVES + (hesitate * (action == last)).reshape(-1, *extra)
                + (1.0 - style.slip - hesitate).reshape(-1, *extra) * plain)

    own = taken(planned)[:, None, :, None, :]  # [B, 1, target, 1, distracted]
    if style.detour == 0:
        return joint * own[..., None]
    along = taken((action[:, None] == np.arange(MOVES)[None]).astype(float))  # [B, direction]
    L = style.detour_len

    def index(left: int, direction: int) -> int:
        """The detour axis's index of ``left`` steps still to walk in ``direction`` (0: none)."""
        return 0 if left == 0 else 1 + MOVES * (left - 1) + direction

    out = np.zeros_like(joint)
    idle = joint[..., 0]  # [B, goal, target, pending, distracted]: on no detour before the step
    out[..., 0] += idle * (1.0 - style.detour) * own
    for direction in range(MOVES):
        weight = along[:, direction].reshape(B, 1, 1, 1, 1)
        out[..., index(L - 1, direction)] += idle * (style.detour / MOVES) * weight
        for left in range(1, L):
            out[..., index(left - 1, direction)] += joint[..., index(left, direction)] * weight
    return out


def planned_moves(model: PersonLeader, block_color: np.ndarray, me: np.ndarray, other: np.ndarray) -> np.ndarray:
    """``[B, C, 4]``: the probability of each move the leader ``model`` plans when pursuing each color (its A* step,
    or its Boltzmann moves; where no block of the color can be reached, its ``wander``: a free move at random)."""
    B, C = block_color.shape[0], model.config.num_colors
    wanted = np.repeat(np.eye(C, dtype=bool)[None], B, axis=0).reshape(B * C, C)  # env-major, color-minor
    blocks = np.repeat(block_color, C, axis=0)
    me_c, other_c = np.repeat(me, C, axis=0), np.repeat(other, C, axis=0)
    if model.style.rationality is not None:
        return model.boltzmann_probs(wanted, blocks, me_c, other_c, model.style.rationality).reshape(B, C, MOVES)
    is_wanted, open_cells, clean = model.cells(wanted, blocks, other_c)
    dist = model.field(is_wanted, open_cells, clean, me_c)
    actions, found = model.mover.descend(dist, me_c, other_c)
    probs = np.eye(MOVES)[actions]
    if not found.all():
        lost = ~found
        nxt, moves = model.mover.neighbours(me_c[lost], other_c[lost])
        free = moves & (blocks[lost].reshape(int(lost.sum()), -1)[np.arange(int(lost.sum()))[:, None], nxt] < 0)
        moves = np.where(free.any(axis=1, keepdims=True), free, moves)
        moves = np.where(moves.any(axis=1, keepdims=True), moves, True)
        probs[lost] = moves / moves.sum(axis=1, keepdims=True)
    return probs.reshape(B, C, MOVES)


def leader_styles(policy: Policy) -> list[PersonStyle]:
    """The true model of a leader policy: its ``PersonStyle`` (the A* leader's: every departure off), one per
    member for a population (in member order); a ``ValueError`` for a leader whose model is not known."""
    from colorgrid.policies.population import PopulationPolicy

    if isinstance(policy, PopulationPolicy):
        if any(isinstance(member, PopulationPolicy) for member in policy.members.values()):
            raise ValueError("bayes-limit: a population inside a population has no member it can be given; flatten it")
        return [leader_styles(member)[0] for member in policy.members.values()]
    if isinstance(policy, PersonLeader):
        return [policy.style]
    if isinstance(policy, AStarLeader):
        return [PersonStyle()]
    if isinstance(policy, StyledLeader):  # a person's departures are known, the trained base's choices are not
        raise ValueError(f"bayes-limit is given its leader's true model, and a person around {policy.style.base!r} "
                         "has none it can be given (its base's own moves have no model): lead with astar, person:... "
                         "around A* or a population of them")
    raise ValueError(f"bayes-limit is given its leader's true model, and the leader {policy.name!r} has none it "
                     "can be given: lead with astar, person:... or a population of them")


@scripted(PolicyCard(belief=True, yardstick="it is given its leader's true model, which only colorgrid eval gives it"))
class LimitFollower(BayesFollower):
    """The Bayesian follower given its leader's true model: the exact posterior over the goal (module docstring),
    acted on by ``bayes``'s rule. ``surprises`` counts the steps where the leader did what its model gives no
    chance (none if the model is the leader's: a test checks it); the belief is then kept as it was."""

    name = "bayes-limit"
    Params = None

    def __init__(self):
        super().__init__(BayesConfig())
        self.leader: Policy | None = None

    def describe(self) -> dict:
        return {"policy": self.name}

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        if config.num_leaders != 1:
            raise ValueError(f"bayes-limit models one leader; this team has {config.num_leaders}")
        super().reset(config, num_envs, agent_index, seed)
        self.leader = None
        self.surprises = 0

    def see_team(self, policies: list[Policy]) -> None:
        """Read the leader's true model (``leader_styles``) and prepare one joint belief per model."""
        cfg = self.config
        self.leader = policies[cfg.leaders[0]]
        self.styles = leader_styles(self.leader)
        self.models, self.joints = [], []
        for style in self.styles:
            model = PersonLeader(style)
            model.reset(cfg, self.num_envs, cfg.leaders[0])
            self.models.append(model)
            self.joints.append(initial_joint(self.num_envs, style, cfg.num_colors))
        self.planned = np.full((self.num_envs, cfg.num_colors, MOVES), 1.0 / MOVES)
        self.last = np.full(self.num_envs, -1, dtype=np.int64)
        self.picked_before = np.zeros(self.num_envs, dtype=bool)

    def member_of(self, rows: np.ndarray) -> np.ndarray:
        """``[n]``: the index of the model leading each of ``rows`` (the member drawn for its episode)."""
        member = getattr(self.leader, "member", None)
        return np.zeros(len(rows), dtype=np.int64) if member is None else np.asarray(member)[rows]

    def update(self, inp: AgentInput, rows: np.ndarray, block_color: np.ndarray, agent_cell: np.ndarray) -> np.ndarray:
        """Weigh the leader's last action and the reward into the joint of ``rows``; plan its next move under each
        color; return the belief over the current goal ``[n, C]``."""
        if self.leader is None:
            raise ValueError("bayes-limit must be given its leader's model, which colorgrid eval does "
                             "(Policy.see_team); it does not play elsewhere")
        cfg, leader = self.config, self.config.leaders[0]
        C = cfg.num_colors
        member = self.member_of(rows)
        fresh = inp.episode_start | ~self.has_prev[rows]
        belief = np.empty((len(rows), C))
        for m, style in enumerate(self.styles):
            mine = member == m
            go, new = mine & ~fresh, mine & fresh
            joint = self.joints[m]
            if go.any():
                slots = rows[go]
                step = leader_step(joint[slots], self.planned[slots], inp.prev_actions[go, leader], self.last[slots],
                                   self.picked_before[slots], style)
                total = step.sum(axis=(1, 2, 3, 4, 5))
                self.surprises += int((total <= 0).sum())
                step = np.where((total > 0)[:, None, None, None, None, None], step, joint[slots])
                reward = reward_likelihood(inp.prev_picked_color[go], inp.prev_reward[go], cfg, inp.penalty_coef,
                                           self.agent_index, 0.0)
                post = step * reward[:, :, None, None, None, None]
                total = post.sum(axis=(1, 2, 3, 4, 5))
                post = np.where((total > 0)[:, None, None, None, None, None],
                                post / np.where(total > 0, total, 1.0)[:, None, None, None, None, None], joint[slots])
                joint[slots] = goal_transition(post, cfg.switch_prob)
            if new.any():
                joint[rows[new]] = initial_joint(int(new.sum()), style, C)
            belief[mine] = joint[rows[mine]].sum(axis=(2, 3, 4, 5))
            if mine.any():
                me, other = agent_cell[mine, leader], agent_cell[mine][:, self.models[m].other_indices]
                self.planned[rows[mine]] = planned_moves(self.models[m], block_color[mine], me, other)
        self.last[rows] = inp.prev_actions[:, leader]
        self.picked_before[rows] = inp.prev_picked_color[:, leader] >= 0
        self.has_prev[rows] = True
        self.belief[rows] = belief
        return belief


def goal_transition(joint: np.ndarray, switch_prob: float) -> np.ndarray:
    """The goal (axis 1) of a joint belief through one step of its Markov chain: it switches to another color
    uniformly with ``switch_prob`` (``bayes.goal_transition``, for any number of axes after the goal)."""
    C = joint.shape[1]
    return (1 - switch_prob) * joint + switch_prob * (joint.sum(axis=1, keepdims=True) - joint) / (C - 1)
