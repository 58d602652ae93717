"""The compiled step of ``BatchEnv``: moves, pickups, respawns, shaping terms and goal switches.

One function, ``step_kernel``, compiled with numba, loops over environments and applies the
rules of ``docs/ENV_CARD.md`` in place on the state arrays and the observation planes. It
draws its random numbers with the same counter-based hash as ``colorgrid.rng`` (re-stated
here for scalars; a test pins the two equal), so results do not depend on batch size,
batch position or which implementation of the hash ran.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from colorgrid import rng
from colorgrid.enums import Role

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_K_STEP = np.uint64(rng._K_STEP)
_K_ATTEMPT = np.uint64(rng._K_ATTEMPT)
_K_INDEX = np.uint64(rng._K_INDEX)
_K_STREAM = np.uint64(rng._K_STREAM)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_STREAM_RESPAWN = np.uint64(rng.STREAM_RESPAWN)
_STREAM_SWITCH = np.uint64(rng.STREAM_SWITCH)
_STREAM_SWITCH_COLOR = np.uint64(rng.STREAM_SWITCH_COLOR)
_TO_UNIT = 1.0 / float(1 << 53)
MAX_RESPAWN_ATTEMPTS = 1_000_000


@njit(cache=True, inline="always")
def _mix(x):
    x = x ^ (x >> _S30)
    x = x * _M1
    x = x ^ (x >> _S27)
    x = x * _M2
    return x ^ (x >> _S31)


@njit(cache=True, inline="always")
def hash64(seed, step, stream, attempt, index):
    """Scalar ``rng.hash64``: all arguments non-negative integers, the result a uint64."""
    counter = (np.uint64(step) * _K_STEP + np.uint64(attempt) * _K_ATTEMPT + np.uint64(index) * _K_INDEX
               + stream * _K_STREAM)
    return _mix(_mix(seed ^ counter) + counter)


PARAMS = [
    ("width", np.int64), ("height", np.int64), ("num_actions", np.int64), ("horizon", np.int64),
    ("distance_threshold", np.int64), ("hemispheres", np.bool_), ("shared_reward", np.bool_),
    ("potential_shaping", np.bool_), ("goal_reward", np.float64), ("wrong_penalty", np.float64),
    ("penalty_coef", np.float64), ("switch_prob", np.float64), ("distance_penalty", np.float64),
    ("potential_scale", np.float64),
]
"""The rules' constants, named once: one record holds them (``pack``), the kernel reads them by name.
Per-agent flags follow as ``[A]`` uint8 fields: ``distance_mask`` (the distance penalty applies to
agent a), ``sees_goal`` (agent a's goal information shows the goal) and ``is_leader`` (agent a's role)."""


def params_dtype(num_agents: int) -> np.dtype:
    return np.dtype([*PARAMS, ("distance_mask", np.uint8, (num_agents,)), ("sees_goal", np.uint8, (num_agents,)),
                     ("is_leader", np.uint8, (num_agents,))], align=True)


def pack(config, penalty_coef: float | None = None) -> np.ndarray:
    """The kernel's parameters for ``config`` (an ``EnvConfig``): a record array of one element.
    ``penalty_coef`` overrides the config's (the env anneals it between steps)."""
    params = np.zeros(1, dtype=params_dtype(config.num_agents))
    p = params[0]
    for name, _ in PARAMS:
        p[name] = getattr(config, name, None) if name not in _DERIVED else _DERIVED[name](config)
    if penalty_coef is not None:
        p["penalty_coef"] = penalty_coef
    p["distance_mask"] = [config.penalised(a) for a in range(config.num_agents)]
    p["sees_goal"] = config.sees_goal
    p["is_leader"] = [role == Role.LEADER for role in config.roles]
    return params


_DERIVED = {
    "shared_reward": lambda c: c.reward_mode == "shared",
    "distance_penalty": lambda c: c.distance_penalty if c.distance_penalty_agents else 0.0,
}


@njit(cache=True)
def write_goal_info(goal_info, b, goal, sees_goal):
    """The goal-information rule, once: env ``b``'s agents who see the goal get its one-hot, the others zeros."""
    for a in range(goal_info.shape[1]):
        for k in range(goal_info.shape[2]):
            goal_info[b, a, k] = 0.0
        if sees_goal[a]:
            goal_info[b, a, goal] = 1.0


@njit(cache=True)
def write_goal_infos(goal_info, envs, goal, sees_goal):
    """``write_goal_info`` for each env in ``envs`` (goal ``[B]`` indexed by env)."""
    for b in envs:
        write_goal_info(goal_info, b, goal[b], sees_goal)


# Rows of the outputs.
O_REWARD, O_BLOCK, O_DISTANCE, O_POTENTIAL, O_TEAM = range(5)  # fout, float32 [5, B, A]
O_GOAL_PICKUP, O_WRONG_PICKUP, O_TRUNCATED, O_TERMINATED = range(4)  # bout, bool [4, B, A]
OK, NO_FREE_CELL, BAD_ACTION = 0, 1, 2


@njit(cache=True)
def step_kernel(actions, agent_cell, block_at, block_cell, block_color, goal, t, seed, score, goal_pickups,
                wrong_pickups, obs, goal_info, move_table, params, fout, picked_color, bout, switched):
    """Advance every env one step, in place. Shapes: B envs, A agents, N blocks, C colors, HW cells.

    actions [B, A]; agent_cell [B, A]; block_at [B, HW] (block id or -1); block_cell [B, N];
    block_color [N]; goal, t [B]; seed [B] uint64; score, goal/wrong pickups [B, A];
    obs [B, P, HW] uint8; goal_info [B, A, C]; move_table [A, HW, num_actions];
    params: the record of ``pack`` (the rules' constants, by name).
    Writes ``fout [5, B, A]`` float32 (``O_*`` rows: reward with shaping, block reward, distance
    and potential terms, team reward), ``picked_color [B, A]`` (-1 if none), ``bout [4, B, A]``
    (goal pickup, wrong pickup, truncated, terminated) and ``switched [B]``. Returns ``OK``,
    ``BAD_ACTION`` (nothing changed) or ``NO_FREE_CELL`` (validation prevents it).
    """
    p = params[0]
    goal_reward, wrong_penalty, penalty_coef, switch_prob = p.goal_reward, p.wrong_penalty, p.penalty_coef, p.switch_prob
    distance_penalty, potential_scale = p.distance_penalty, p.potential_scale
    width, height, hemispheres = p.width, p.height, p.hemispheres
    distance_threshold, potential_on = p.distance_threshold, p.potential_shaping
    distance_mask, sees_goal, is_leader = p.distance_mask, p.sees_goal, p.is_leader
    for b in range(actions.shape[0]):
        for a in range(actions.shape[1]):
            if actions[b, a] < 0 or actions[b, a] >= p.num_actions:
                return BAD_ACTION
    horizon, shared = p.horizon, p.shared_reward
    B, A = actions.shape
    block_reward = np.zeros(A)
    distance_term = np.zeros(A)
    potential_term = np.zeros(A)
    C = goal_info.shape[2]
    N = block_cell.shape[1]
    span = width // 2 if hemispheres else width
    for b in range(B):
        step_index = t[b] + 1
        # moves in agent order (leaders, then followers); an agent is blocked by the others' current cells:
        # the new cells of those that moved before it, the old cells of those still to move
        for a in range(A):
            old = agent_cell[b, a]
            new = move_table[a, old, actions[b, a]]
            for o in range(A):
                if o != a and new == agent_cell[b, o]:
                    new = old
            obs[b, C + a, old] = 0
            obs[b, C + a, new] = 1
            agent_cell[b, a] = new
        # pickups in agent order; a collected block respawns before the next agent collects
        for a in range(A):
            cell = agent_cell[b, a]
            j = block_at[b, cell]
            block_reward[a] = 0.0
            picked_color[b, a] = -1
            bout[O_GOAL_PICKUP, b, a] = False
            bout[O_WRONG_PICKUP, b, a] = False
            if j < 0:
                continue
            color = block_color[j]
            hit = color == goal[b]
            picked_color[b, a] = color
            bout[O_GOAL_PICKUP, b, a] = hit
            bout[O_WRONG_PICKUP, b, a] = not hit
            reward = goal_reward if hit else -wrong_penalty * penalty_coef
            block_reward[a] = reward
            score[b, a] += reward
            if hit:
                goal_pickups[b, a] += 1
            else:
                wrong_pickups[b, a] += 1
            block_at[b, cell] = -1
            obs[b, color, cell] = 0
            lo = span if (hemispheres and cell % width >= span) else 0
            placed = False
            for k in range(MAX_RESPAWN_ATTEMPTS):
                draw = np.int64(hash64(seed[b], step_index, _STREAM_RESPAWN, k, a) % np.uint64(height * span))
                target = (draw // span) * width + draw % span + lo
                if block_at[b, target] >= 0:
                    continue
                free = True
                for o in range(A):
                    if agent_cell[b, o] == target:
                        free = False
                if free:
                    block_at[b, target] = j
                    block_cell[b, j] = target
                    obs[b, color, target] = 1
                    placed = True
                    break
            if not placed:
                return NO_FREE_CELL
        # shaping terms (reported separately; the caller adds them to rewards)
        for a in range(A):
            distance_term[a] = 0.0
            potential_term[a] = 0.0
        if distance_penalty != 0.0:  # an agent within the threshold of an agent of the other role
            for a in range(A):
                if distance_mask[a] == 0:
                    continue
                ra, ca = agent_cell[b, a] // width, agent_cell[b, a] % width
                for o in range(A):
                    if is_leader[o] != is_leader[a]:
                        ro, co = agent_cell[b, o] // width, agent_cell[b, o] % width
                        if abs(ra - ro) + abs(ca - co) <= distance_threshold:
                            distance_term[a] = -distance_penalty
        if potential_on:
            for a in range(A):
                ra, ca = agent_cell[b, a] // width, agent_cell[b, a] % width
                total = 0.0
                for j in range(N):
                    cell = block_cell[b, j]
                    d = abs(cell // width - ra) + abs(cell % width - ca)
                    weight = 1.0 if block_color[j] == goal[b] else -wrong_penalty
                    total += (1.0 / (d + 1.0)) * weight
                potential_term[a] = potential_scale * total
        team = 0.0
        for a in range(A):
            team += block_reward[a]
        for a in range(A):
            own = team if shared else block_reward[a]
            fout[O_REWARD, b, a] = (own + distance_term[a]) + potential_term[a]
            fout[O_BLOCK, b, a] = block_reward[a]
            fout[O_DISTANCE, b, a] = distance_term[a]
            fout[O_POTENTIAL, b, a] = potential_term[a]
            fout[O_TEAM, b, a] = team
            bout[O_TRUNCATED, b, a] = step_index >= horizon
            bout[O_TERMINATED, b, a] = False
        # the step ends; then the goal may switch to one of the other colors
        t[b] = step_index
        switched[b] = False
        if switch_prob > 0.0:
            u = np.float64(hash64(seed[b], step_index, _STREAM_SWITCH, 0, 0) >> _S11) * _TO_UNIT
            if u < switch_prob:
                offset = 1 + np.int64(hash64(seed[b], step_index, _STREAM_SWITCH_COLOR, 0, 0) % np.uint64(C - 1))
                goal[b] = (goal[b] + offset) % C
                switched[b] = True
                write_goal_info(goal_info, b, goal[b], sees_goal)
    return OK
