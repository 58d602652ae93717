"""The fast network's input view, cut from the uint8 board in one compiled pass per kind (CPU).

``FastEncoder.prepare`` needs, for every sample, the egocentric window cut into its first
conv's 3x3 patches and every plane average-pooled. Built with tensor ops that is a padded
copy of the board, a gather, two float conversions and a pooling of a float copy of the
board: a dozen small ops at a rollout's batch. These kernels write the same float32 values
straight from the board (docs/PERFORMANCE.md has the bench before and after).
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit


@njit(cache=True, nogil=True)
def _window_patches(obs, me, radius, cells, out):
    """``out [N, cells^2, P + 1, 9]``: the ``3 * cells`` square of the window of ``obs [N, P, H, W]`` whose top-left
    corner is ``radius`` cells up and left of ``me [N, 2]``, as 3x3 patches; plane ``P`` is 1 on the grid."""
    N, P, H, W = obs.shape
    side = 3 * cells
    out[:] = 0.0  # beyond the walls
    for n in range(N):
        top, left = me[n, 0] - radius, me[n, 1] - radius
        for r in range(max(0, -top), min(side, H - top)):  # the window's rows on the grid
            row, first, kh = top + r, (r // 3) * cells, (r % 3) * 3
            for c in range(max(0, -left), min(side, W - left)):
                cell, k, col = first + c // 3, kh + c % 3, left + c
                for p in range(P):
                    out[n, cell, p, k] = obs[n, p, row, col]
                out[n, cell, P, k] = 1.0


@njit(cache=True, nogil=True)
def _pooled(obs, pool, out):
    """``out [N, P, ceil(H / pool), ceil(W / pool)]``: the mean of each ``pool x pool`` block of ``obs [N, P, H, W]``
    (blocks cut by the far edges: the mean of the cells they hold), as ``avg_pool2d(ceil_mode=True)`` computes it."""
    N, P, H, W = obs.shape
    rows = np.empty(W, dtype=np.int32)  # one band of ``pool`` rows summed down each column
    for n in range(N):
        for p in range(P):
            for i in range(out.shape[2]):
                r0, r1 = i * pool, min(i * pool + pool, H)
                rows[:] = 0
                for r in range(r0, r1):
                    for c in range(W):  # contiguous: vectorised
                        rows[c] += obs[n, p, r, c]
                for j in range(out.shape[3]):
                    c0, c1 = j * pool, min(j * pool + pool, W)
                    total = 0
                    for c in range(c0, c1):
                        total += rows[c]
                    out[n, p, i, j] = np.float32(total) / np.float32((r1 - r0) * (c1 - c0))


def window_patches(obs: torch.Tensor, me: torch.Tensor, radius: int, cells: int,
                   out: torch.Tensor | None = None) -> torch.Tensor:
    """``[N, cells^2, P + 1, 9]`` float32 from ``obs [N, P, H, W]`` (uint8, CPU) and own cells ``me [N, 2]``, written
    into ``out`` (contiguous) if given."""
    N, P = obs.shape[:2]
    out = torch.empty(N, cells * cells, P + 1, 9) if out is None else out
    _window_patches(obs.numpy(), me.to(torch.int64).numpy(), radius, cells, out.numpy())
    return out


def pooled(obs: torch.Tensor, pool: int, out: torch.Tensor | None = None) -> torch.Tensor:
    """``avg_pool2d(obs.float(), pool, ceil_mode=True)`` of ``obs [N, P, H, W]`` (uint8, CPU), flattened: ``[N, -1]``,
    written into ``out`` (contiguous) if given."""
    N, P, H, W = obs.shape
    shape = (N, P, -(-H // pool), -(-W // pool))
    grid = torch.empty(shape) if out is None else out.view(shape)
    _pooled(obs.numpy(), pool, grid.numpy())
    return grid.reshape(N, -1)
