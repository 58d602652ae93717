"""Batched grid reasoning for scripted agents: decoding planes, distance fields, greedy steps."""

from __future__ import annotations

import numpy as np
from numba import njit

from colorgrid.config import EnvConfig
from colorgrid.env import move_table
from colorgrid.roles import columns

INF = np.int32(1 << 20)


def decode(observation: np.ndarray, config: EnvConfig):
    """Planes -> ``block_color [B, H, W]`` (-1 if none; else the first color of the largest plane value, as
    ``argmax``) and ``agent_cell [B, A]`` (each agent plane's first largest cell). Compiled (``_decode``)."""
    observation = np.ascontiguousarray(observation)
    B, P, H, W = observation.shape
    if P != config.num_planes:
        raise ValueError(f"observation has {P} planes; this config's have {config.num_planes} (colors, then agents)")
    block_color = np.empty((B, H * W), dtype=np.int64)
    agent_cell = np.empty((B, config.num_agents), dtype=np.int64)
    _decode(observation.reshape(B, P, H * W), config.num_colors, block_color, agent_cell)
    return block_color.reshape(B, H, W), agent_cell


@njit(cache=True, nogil=True)
def _decode(planes, C, block_color, agent_cell):
    """``decode`` on ``planes [B, P, H * W]``: ``block_color [B, H * W]`` and ``agent_cell [B, P - C]``."""
    B, P, N = planes.shape
    for b in range(B):
        for cell in range(N):
            best, found = 0, False
            for c in range(C):
                value = planes[b, c, cell]
                found |= value != 0
                if value > planes[b, best, cell]:
                    best = c
            block_color[b, cell] = best if found else -1
        for a in range(P - C):
            best = 0
            for cell in range(N):
                if planes[b, C + a, cell] > planes[b, C + a, best]:
                    best = cell
            agent_cell[b, a] = best


def allowed_cells(config: EnvConfig, agent_index: int) -> np.ndarray:
    """[H, W] bool: cells this agent may stand on (its half in hemisphere mode, ``roles.columns``)."""
    first, stop = columns(config, agent_index)
    mask = np.zeros((config.height, config.width), dtype=bool)
    mask[:, first:stop] = True
    return mask


def distance_field(targets: np.ndarray, passable: np.ndarray, start_cell: np.ndarray | None = None) -> np.ndarray:
    """[B, H, W] int32 shortest 4-connected path lengths to the nearest target (``INF`` if none).

    targets, passable: [B, H, W] bool (targets must be passable to count). With ``start_cell [B]`` only the
    distances up to the farthest start cell's are kept (``INF`` beyond), which is all a greedy step needs (the
    start's neighbours on a shortest path are final by then): the field that a breadth-first relaxation of the
    whole batch at once, stopped as soon as every env's start cell is reached, leaves. Where a start cannot be
    reached, every env's field is whole. One compiled breadth-first search an env (``_search``).
    """
    B, H, W = targets.shape
    start = np.full(B, -1, dtype=np.int64) if start_cell is None else np.asarray(start_cell, dtype=np.int64)
    outside = start_cell is not None and ((start < 0) | (start >= H * W)).any()
    if passable.shape != targets.shape or start.shape != (B,) or outside:
        raise ValueError(f"distance_field needs targets and passable of one shape [B, H, W] and a start cell in "
                         f"[0, H*W) for each env: got {targets.shape}, {passable.shape} and start cells "
                         f"{start_cell if start_cell is None else start.shape}")
    dist = np.empty((B, H * W), dtype=np.int32)
    _search(np.ascontiguousarray(targets).reshape(B, H * W), np.ascontiguousarray(passable).reshape(B, H * W), W,
            start, dist)
    return dist.reshape(B, H, W)


@njit(cache=True, nogil=True)
def _search(targets, passable, W, start, dist):
    """``dist [B, H * W]``: each env's breadth-first search from its passable targets over its passable cells, up
    to each ``start`` cell (``-1``: none, for a whole field) and then on to the farthest start's distance (to the end
    where a start is unreached)."""
    B, N = targets.shape
    queue = np.empty((B, N), dtype=np.int64)
    head, tail = np.zeros(B, dtype=np.int64), np.zeros(B, dtype=np.int64)
    farthest = 0
    for b in range(B):
        for cell in range(N):
            if targets[b, cell] and passable[b, cell]:
                dist[b, cell] = 0
                queue[b, tail[b]] = cell
                tail[b] += 1
            else:
                dist[b, cell] = INF
        s = start[b]
        while head[b] < tail[b] and (s < 0 or dist[b, s] == INF):
            _visit(b, passable, W, dist, queue, head, tail)
        farthest = max(farthest, INF if s < 0 else dist[b, s])
    for b in range(B):
        while head[b] < tail[b] and dist[b, queue[b, head[b]]] < farthest:
            _visit(b, passable, W, dist, queue, head, tail)


@njit(cache=True, nogil=True, inline="always")
def _visit(b, passable, W, dist, queue, head, tail):
    """Env ``b``'s next queued cell: its unvisited passable neighbours get its distance plus one, queued."""
    cell = queue[b, head[b]]
    head[b] += 1
    r, c = divmod(cell, W)
    H, d = passable.shape[1] // W, dist[b, cell] + 1
    for nr, nc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
        n = nr * W + nc
        if 0 <= nr < H and 0 <= nc < W and passable[b, n] and dist[b, n] == INF:
            dist[b, n] = d
            queue[b, tail[b]] = n
            tail[b] += 1


class Mover:
    """Turns distance fields into actions for one agent (walls, halves and the other agents applied).

    ``other_cells`` are ``[B, K]``: the cells of the K agents this one must not step onto (every other
    agent of the team); ``[B]`` is read as K = 1.
    """

    def __init__(self, config: EnvConfig, agent_index: int):
        self.config = config
        self.agent_index = agent_index
        self.table = move_table(config)[agent_index]  # [H*W, num_moves]
        self.num_moves = 4  # scripted agents move; stay is never needed to follow a path

    def neighbours(self, cell: np.ndarray, other_cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``[B, 4]`` target cells of the four moves and whether each really moves the agent (not into a wall,
        its half's edge or another agent's cell)."""
        nxt = self.table[cell, : self.num_moves]
        others = other_cells.reshape(cell.shape[0], -1)
        moves = (nxt != cell[:, None]) & ~(nxt[:, :, None] == others[:, None, :]).any(axis=2)
        return nxt, moves

    def descend(self, dist: np.ndarray, cell: np.ndarray, other_cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Greedy step down ``dist``: ``actions [B]`` and ``found [B]`` (a finite neighbour existed).

        Ties go to the first move in action order (up, down, left, right).
        """
        B = dist.shape[0]
        return self._step(dist.reshape(B, -1), np.arange(B), cell, other_cells)

    def _step(self, flat: np.ndarray, rows: np.ndarray, cell: np.ndarray, other_cells: np.ndarray):
        """``descend`` for the envs ``rows`` of ``flat [B, H*W]`` distances (``cell``, ``other_cells``: theirs)."""
        nxt, moves = self.neighbours(cell, other_cells)
        values = np.where(moves, flat[rows[:, None], nxt], INF)
        return values.argmin(axis=1), values.min(axis=1) < INF

    def destination(self, dist: np.ndarray, cell: np.ndarray, other_cells: np.ndarray) -> np.ndarray:
        """``[B]``: the target cell (``dist == 0``) that repeated ``descend`` steps from ``cell`` reach if nothing
        else moves, or -1 where ``dist`` is infinite at ``cell``. Each step lowers the distance by one, so
        this takes at most the largest finite ``dist[cell]`` rounds (a batched loop over steps, not envs).
        """
        B = dist.shape[0]
        flat = dist.reshape(B, -1)
        cell = cell.copy()
        others = other_cells.reshape(B, -1)
        target = np.full(B, -1, dtype=np.int64)
        start = flat[np.arange(B), cell]
        walking = np.arange(B)[start < INF]
        for _ in range(int(start[walking].max(initial=0)) + 1):  # one round per step of the longest walk
            here = cell[walking]
            arrived = flat[walking, here] == 0
            target[walking[arrived]] = here[arrived]
            walking = walking[~arrived]
            if not walking.size:
                break
            actions, _ = self._step(flat, walking, cell[walking], others[walking])
            cell[walking] = self.table[cell[walking], actions]
        return target

    def wander(self, block_color: np.ndarray, cell: np.ndarray, other_cells: np.ndarray,
               rng: np.random.Generator, avoid_blocks: bool = True) -> np.ndarray:
        """A random move to a neighbouring cell with no block (any move if none is free)."""
        B = cell.shape[0]
        nxt, moves = self.neighbours(cell, other_cells)
        if avoid_blocks:
            free = moves & (block_color.reshape(B, -1)[np.arange(B)[:, None], nxt] < 0)
            moves = np.where(free.any(axis=1, keepdims=True), free, moves)
        noise = rng.random((B, self.num_moves)) + moves * 2.0  # prefer allowed moves, random among them
        return noise.argmax(axis=1)


def manhattan_to_nearest(config: EnvConfig, block_color: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """``[B, K, C]``: Manhattan distance from each of ``cells [B, K]`` to the nearest block of each color, ``H + W``
    where an env has no block of that color.

    In play every env holds the same number of blocks of each color (``blocks_per_color``): the blocks are
    then gathered as ``[B, n]``; a board built otherwise is measured cell by cell.
    """
    B, H, W = block_color.shape
    rows, cols = np.divmod(cells, W)  # [B, K]
    flat = block_color.reshape(B, -1)
    out = np.empty(cells.shape + (config.num_colors,), dtype=np.float64)
    for k in range(config.num_colors):
        env_idx, block_cells = np.nonzero(flat == k)
        counts = np.bincount(env_idx, minlength=B)
        if counts[0] > 0 and (counts == counts[0]).all():
            br, bc = np.divmod(block_cells.reshape(B, 1, -1), W)  # [B, 1, n]
            extra = 0
        else:  # every cell, those without a block of this color pushed out of reach
            br, bc = np.divmod(np.arange(H * W), W)
            extra = np.where(flat == k, 0, H + W)[:, None, :]  # [B, 1, H * W]
        dist = np.abs(br - rows[:, :, None]) + np.abs(bc - cols[:, :, None]) + extra
        out[..., k] = np.minimum(dist.min(axis=2), H + W)
    return out


def unsure_moves(observation: np.ndarray, belief: np.ndarray, moves: np.ndarray, config: EnvConfig, agent: int,
                 min_belief: float) -> np.ndarray:
    """``[B, actions]`` bool: the moves of ``agent`` (``moves [H*W, actions]``: the cell each leads to, for the
    actions it can choose) onto a block whose color ``belief [B, C]`` gives less than ``min_belief``; none in a
    row where every move is one (the agent must go somewhere)."""
    block_color, cells = decode(observation, config)
    B = len(block_color)
    ahead = block_color.reshape(B, -1)[np.arange(B)[:, None], moves[cells[:, agent]]]  # [B, actions]
    unsure = (ahead >= 0) & (np.take_along_axis(belief, np.maximum(ahead, 0), axis=1) < min_belief)
    unsure[unsure.all(axis=1)] = False
    return unsure


def kept_off(*masks: np.ndarray | None) -> np.ndarray | None:
    """The moves ``masks`` take out (each ``[B, actions]`` bool, or None), the most important first. In a row where
    together they would take out every move, the last mask is lifted there, then the one before, until a move is
    left; none is taken out where the first alone takes out every move (the agent must go somewhere). None when
    every mask is None."""
    given = [m for m in masks if m is not None]
    if not given:
        return None
    out = np.logical_or.reduce(given)
    for kept in range(len(given) - 1, -1, -1):
        full = out.all(axis=1)
        if not full.any():
            break
        out[full] = np.logical_or.reduce(given[:kept])[full] if kept else False
    return out
