"""Hand-built states from text maps, for tests and experiments.

A map has one line per row; ``.`` is floor, an agent's symbol (``config.symbols``: ``L`` the
leader and ``F`` the follower of the 1:1 team; ``L1``, ``L2``, ``F1``, ... in other teams) marks it
and a color's initial (``r``, ``g``, ``b``, ...) a block of that color::

    state = state_from_text(config, '''
        L.r
        .g.
        b.F
    ''', goal="red")
"""

from __future__ import annotations

import re
import textwrap

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.state import EnvState


def state_from_text(config: EnvConfig, text: str, goal: int | str = 0, seed: int = 0, t: int = 0) -> EnvState:
    """A batch-of-one state drawn from ``text`` (see the module docstring).

    The map must be ``config.height x config.width``, hold each agent once and
    exactly ``config.blocks_per_color`` blocks of each color.
    """
    rows = [re.findall(r"[LF]\d+|\S", line) for line in textwrap.dedent(text).strip().splitlines()]
    symbols = config.symbols
    if len(rows) != config.height or any(len(r) != config.width for r in rows):
        raise ValueError(f"map must be {config.height} rows of {config.width} cells, got "
                         f"{len(rows)} rows of lengths {sorted({len(r) for r in rows})}")
    initials = {name[0]: k for k, name in enumerate(config.color_names)}
    if len(initials) != config.num_colors:
        raise ValueError("color initials collide; maps support colors with distinct initials only")
    goal_index = config.color_names.index(goal) if isinstance(goal, str) else int(goal)
    agent_cell = np.full(config.num_agents, -1, dtype=np.int64)
    cells_by_color: list[list[int]] = [[] for _ in range(config.num_colors)]
    for r, row in enumerate(rows):
        for c, ch in enumerate(row):
            cell = r * config.width + c
            if ch in symbols:
                if agent_cell[symbols.index(ch)] >= 0:
                    raise ValueError(f"map places agent {ch} twice")
                agent_cell[symbols.index(ch)] = cell
            elif ch in initials:
                cells_by_color[initials[ch]].append(cell)
            elif ch != ".":
                raise ValueError(f"unknown map character {ch!r} at row {r}, col {c}; allowed: . "
                                 + " ".join([*symbols, *initials]))
    if (agent_cell < 0).any():
        raise ValueError(f"map must place every agent {list(config.agent_names)} ({' '.join(symbols)})")
    for k, cells in enumerate(cells_by_color):
        if len(cells) != config.blocks_per_color:
            raise ValueError(f"map has {len(cells)} {config.color_names[k]} blocks; the config needs "
                             f"exactly {config.blocks_per_color} per color")
    block_cell = np.array([c for cells in cells_by_color for c in cells], dtype=np.int64)
    block_at = np.full(config.height * config.width, -1, dtype=np.int32)
    block_at[block_cell] = np.arange(config.num_blocks)
    A = config.num_agents
    return EnvState(
        seed=np.array([seed], dtype=np.uint64),
        t=np.array([t], dtype=np.int64),
        goal=np.array([goal_index], dtype=np.int64),
        agent_cell=agent_cell[None, :],
        block_cell=block_cell[None, :],
        block_at=block_at.reshape(1, config.height, config.width),
        score=np.zeros((1, A)),
        goal_pickups=np.zeros((1, A), dtype=np.int64),
        wrong_pickups=np.zeros((1, A), dtype=np.int64),
    )
