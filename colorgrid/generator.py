"""Initial states: where agents and blocks start, and the first goal color."""

from __future__ import annotations

import numpy as np
from numba import njit

from colorgrid import rng
from colorgrid.config import EnvConfig
from colorgrid.roles import columns


def block_goes_left(config: EnvConfig) -> np.ndarray:
    """[N] bool: in hemisphere mode, blocks with even index start in the leaders' (left) half.

    Alternating by index spreads every color evenly over both halves.
    """
    return np.arange(config.num_blocks) % 2 == 0


def _shuffled_prefix(seeds: np.ndarray, cells: np.ndarray, count: int, offset: int) -> np.ndarray:
    """[n, count]: the first ``count`` cells of a uniform random permutation of ``cells``.

    A partial Fisher-Yates shuffle, vectorised over envs (the loop runs over
    positions, not envs). ``offset`` keeps the draws of different halves apart.
    """
    n, m = seeds.shape[0], cells.shape[0]
    perm = np.tile(cells, (n, 1))
    k = np.arange(count)
    picks = k + rng.below(seeds[:, None], m - k, 0, rng.STREAM_LAYOUT, index=offset + k)  # [n, count]
    swap_prefix(perm, picks)
    return perm[:, :count]


@njit(cache=True)
def swap_prefix(perm: np.ndarray, picks: np.ndarray) -> None:
    """The Fisher-Yates swaps: for each row, position k takes the element at ``picks[k]`` (>= k), in order."""
    for r in range(perm.shape[0]):
        for k in range(picks.shape[1]):
            j = picks[r, k]
            perm[r, k], perm[r, j] = perm[r, j], perm[r, k]


def initial_layout(config: EnvConfig, seeds: np.ndarray):
    """Draw starting cells for episodes with the given seeds.

    seeds: [n] uint64. Returns ``agent_cell [n, A]``, ``block_cell [n, N]`` (flat
    cells ``row * W + col``, all distinct) and ``goal [n]``. Without hemispheres
    the agents (in index order) and then the blocks take the first cells of a random permutation
    of the grid; with them, the leaders and the even-indexed blocks come from the left half's
    permutation, the followers and the odd-indexed blocks from the right half's (``roles.columns``).
    """
    H, W = config.height, config.width
    A, N = config.num_agents, config.num_blocks
    cells = np.arange(H * W)
    if not config.hemispheres:
        order = _shuffled_prefix(seeds, cells, A + N, 0)
        agent_cell, block_cell = order[:, :A], order[:, A:]
    else:
        goes_left = block_goes_left(config)
        L, F = config.num_leaders, config.num_followers
        first_follower = config.followers[0]
        left = _shuffled_prefix(seeds, _half(config, cells, 0), L + goes_left.sum(), 0)
        right = _shuffled_prefix(seeds, _half(config, cells, first_follower), F + (~goes_left).sum(), H * W)
        agent_cell = np.concatenate([left[:, :L], right[:, :F]], axis=1)
        block_cell = np.empty((seeds.shape[0], N), dtype=np.int64)
        block_cell[:, goes_left] = left[:, L:]
        block_cell[:, ~goes_left] = right[:, F:]
    goal = rng.below(seeds, config.num_colors, 0, rng.STREAM_GOAL)
    return agent_cell.astype(np.int64), block_cell.astype(np.int64), goal


def _half(config: EnvConfig, cells: np.ndarray, agent: int) -> np.ndarray:
    """The ``cells`` (flat indices) in the columns agent ``agent`` may stand on."""
    first, stop = columns(config, agent)
    col = cells % config.width
    return cells[(col >= first) & (col < stop)]
