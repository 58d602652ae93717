"""The state of a batch of ColorGrid environments: plain arrays, leading batch axis."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, fields

import numpy as np

from colorgrid.config import EnvConfig


@dataclass
class EnvState:
    """Everything that determines the future of a batch of B environments.

    Shapes use B = batch, A = agents (leader first), N = blocks, H x W = grid.
    Block ``j`` has color ``j // config.blocks_per_color`` for its whole life.
    """

    seed: np.ndarray  # [B] uint64: seed of the current episode (all its randomness derives from it)
    t: np.ndarray  # [B] int64: steps taken in the current episode
    goal: np.ndarray  # [B] int64: current goal color
    agent_cell: np.ndarray  # [B, A] int64: cell of each agent, as row * W + col
    block_cell: np.ndarray  # [B, N] int64: cell of each block, as row * W + col
    block_at: np.ndarray  # [B, H, W] int32: index of the block in a cell, -1 if none
    score: np.ndarray  # [B, A] float64: block rewards collected this episode
    goal_pickups: np.ndarray  # [B, A] int64: goal-color blocks collected this episode
    wrong_pickups: np.ndarray  # [B, A] int64: other-color blocks collected this episode

    @property
    def width(self) -> int:
        return int(self.block_at.shape[-1])

    @property
    def agent_pos(self) -> np.ndarray:
        """[B, A, 2] int64: (row, col) of each agent."""
        return np.stack(np.divmod(self.agent_cell, self.width), axis=-1)

    @property
    def block_pos(self) -> np.ndarray:
        """[B, N, 2] int64: (row, col) of each block."""
        return np.stack(np.divmod(self.block_cell, self.width), axis=-1)

    @property
    def batch_size(self) -> int:
        return int(self.t.shape[0])

    def select(self, index) -> "EnvState":
        """A copy holding only env(s) ``index`` (an int gives a batch of one)."""
        idx = np.atleast_1d(np.asarray(index))
        return EnvState(**{f.name: getattr(self, f.name)[idx].copy() for f in fields(self)})

    def copy(self) -> "EnvState":
        return EnvState(**{f.name: getattr(self, f.name).copy() for f in fields(self)})

    def block_colors(self, config: EnvConfig) -> np.ndarray:
        """[B, H, W] int64: color of the block in each cell, -1 if none."""
        return np.where(self.block_at >= 0, self.block_at // config.blocks_per_color, -1)

    def state_hash(self, index: int = 0) -> str:
        """A 16-hex-digit digest of env ``index``'s state (used by replays to verify)."""
        h = hashlib.blake2b(digest_size=8)
        for name in ("t", "goal", "agent_cell", "block_at"):
            h.update(np.ascontiguousarray(getattr(self, name)[index], dtype=np.int64).tobytes())
        return h.hexdigest()
