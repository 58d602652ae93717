"""Frames replays from observation arrays: each frame's cells read back, and the block count they hold.

A frames replay stores every state's cells (docs/REPLAY_FORMAT.md); its config's block density must give as
many blocks of each color as the frames hold, since a state numbers its blocks color by color
(``EnvState.block_colors``). The import reads that count from the frames and fits the density to it.
"""

from __future__ import annotations

import math

import numpy as np

from colorgrid.config import LEADER, EnvConfig
from colorgrid.replay.format import Replay, ReplayError
from colorgrid.replay.blocks import encode_blocks


def import_frames(config: EnvConfig, planes: np.ndarray, goal_info: np.ndarray, meta: dict | None = None,
                  fixed_density: bool = False) -> Replay:
    """A frames replay from observation arrays in this project's layout (``colorgrid.paper_format`` maps the
    paper's dumps to it).

    planes: ``[T+1, C+A, H, W]`` (or ``[T+1, A, C+A, H, W]``, the first leader's view is used), 0/1 per cell;
    goal_info: ``[T+1, C]`` (or ``[T+1, A, C]``) one-hot goal per frame (the leader's view). The replay's config
    is ``config`` with the block density that gives the frames' count of each color (``fit_block_density``);
    ``fixed_density``: ``config``'s density was chosen by the user, so frames that hold another count are
    refused, naming the density that fits them. Frames a state cannot hold raise ``ReplayError``.
    """
    planes = np.asarray(planes)
    goal_info = np.asarray(goal_info)
    if planes.ndim == 5:
        planes = planes[:, LEADER]
    C, A, H, W = config.num_colors, config.num_agents, config.height, config.width
    if planes.ndim != 4 or planes.shape[1:] != (config.num_planes, H, W):
        raise ReplayError(None, f"trajectory must have shape [T, {config.num_planes}, {H}, {W}] for this config, "
                                f"got {list(planes.shape)}")
    if goal_info.ndim == 3:
        goal_info = goal_info[:, LEADER]
    if goal_info.shape != (planes.shape[0], C):
        raise ReplayError(None, f"goal info must have shape [{planes.shape[0]}, {C}] (one row per frame of the "
                                f"trajectory), got {list(goal_info.shape)}")
    if planes.shape[0] < 2:
        raise ReplayError(None, "a trajectory needs at least 2 frames (one step)")
    if not np.isin(planes, (0, 1)).all():
        raise ReplayError(None, "trajectory planes must hold only 0s and 1s (a cell holds a block or an agent, or not)")
    if not (goal_info.sum(axis=1) == 1).all():
        raise ReplayError(None, "goal info rows must be one-hot (the leader's view of the goal)")
    color = block_colors(planes[:, :C])  # [T+1, H*W]
    config = fit_block_density(config, blocks_per_color(color, config), fixed_density)
    blocks, cells = [], []
    for t, frame in enumerate(planes):
        agent_counts = frame[C:].reshape(A, -1).sum(axis=1)
        if not (agent_counts == 1).all():
            raise ReplayError(None, f"frame {t}: each agent plane must mark exactly one cell")
        blocks.append(encode_blocks(color[t]))
        cells.append(frame[C:].reshape(A, -1).argmax(axis=1).tolist())
    goals = goal_info.argmax(axis=1).astype(int).tolist()
    T = planes.shape[0] - 1
    return Replay(config=config, seed=None, source="import",
                  agents={name: {"policy": "unknown"} for name in config.agent_names},
                  actions=None, goal=goals[:T], block_reward=None, team_reward=None, picked_color=None,
                  goal_switched=None, frames={"agent_cell": cells, "blocks": blocks, "goal": goals},
                  meta=dict(meta or {}))


def block_colors(color_planes: np.ndarray) -> np.ndarray:
    """``[T, C, H, W]`` 0/1 color planes to each cell's color, ``[T, H*W]`` (-1: no block); a cell marked in two
    color planes raises ``ReplayError``."""
    stacked = color_planes.sum(axis=1)
    if (stacked > 1).any():
        t, row, col = np.argwhere(stacked > 1)[0]
        raise ReplayError(None, f"frame {t}: cell (row {row}, col {col}) holds blocks of two colors")
    colors = np.where(stacked > 0, color_planes.argmax(axis=1), -1)
    return colors.reshape(len(colors), -1)


def blocks_per_color(colors: np.ndarray, config: EnvConfig) -> int:
    """The number of blocks of each color that every frame of ``colors`` (``[T, H*W]``, -1 none) holds; frames
    whose colors hold different counts, or change them, raise ``ReplayError`` naming the counts by color."""
    names = config.color_names
    counts = np.stack([(colors == k).sum(axis=1) for k in range(config.num_colors)], axis=1)  # [T, C]

    def listed(row) -> str:
        return ", ".join(f"{int(n)} {name}" for n, name in zip(row, names))

    if len(set(counts[0].tolist())) > 1:
        raise ReplayError(None, f"frame 0 holds {listed(counts[0])} blocks; a replay's states hold the same number "
                                f"of each color (the block density)")
    changed = np.flatnonzero((counts != counts[0]).any(axis=1))
    if changed.size:
        t = changed[0]
        raise ReplayError(None, f"frame {t} holds {listed(counts[t])} blocks, frame 0 {int(counts[0, 0])} of each; "
                                f"a replay's states keep every color's count (a collected block respawns)")
    return int(counts[0, 0])


def fit_block_density(config: EnvConfig, per_color: int, fixed: bool = False) -> EnvConfig:
    """``config`` with a block density that gives ``per_color`` blocks of each color: its own if it does, else
    the shortest decimal that does (17 of each on 32x32: 0.05). ``fixed``: refuse instead of changing it. A count
    no config can hold raises ``ReplayError`` naming the density it would take."""
    if config.blocks_per_color == per_color:
        return config
    exact = per_color * config.num_colors / (config.height * config.width)
    fitted = None
    for digits in range(1, 10):  # the first decimal at or above `exact` that floors to the count
        density = round(math.ceil(exact * 10 ** digits - 1e-6) / 10 ** digits, digits)
        try:
            candidate = config.replace(block_density=density)
        except ValueError as err:
            raise ReplayError(None, f"the frames hold {per_color} blocks of each color (block density {density:g}), "
                                    f"which no config of this board can hold: {err}") from None
        if candidate.blocks_per_color == per_color:
            fitted = candidate
            break
    fitted = fitted or config.replace(block_density=exact)
    if fixed:
        raise ReplayError(None, f"block_density={config.block_density:g} gives {config.blocks_per_color} blocks of "
                                f"each color, but the frames hold {per_color}: block_density={fitted.block_density:g} "
                                f"fits them (or leave it out: the import reads it from the frames)")
    return fitted


def describe_frames(replay: Replay) -> str:
    """A frames replay in a line: ``127 steps, 17 blocks of each color (block density 0.05), goal blue then green``."""
    cfg, goals = replay.config, replay.frames["goal"]
    order = [cfg.color_names[g] for i, g in enumerate(goals) if i == 0 or g != goals[i - 1]]
    shown = " then ".join(order[:4]) + (f" and {len(order) - 4} more switches" if len(order) > 4 else "")
    return (f"{replay.num_steps} steps, {cfg.blocks_per_color} blocks of each color (block density "
            f"{cfg.block_density:g}), goal {shown}")
