"""The paper's released code (``run_ppo.py``, ``color_maze.py``) and this project: its conventions, mapped once.

The paper's code holds a board as planes ``[RED, BLUE, GREEN, leader, follower]``, each indexed
``[x, y]``; its actions are ``UP`` (y + 1), ``DOWN`` (y - 1), ``LEFT`` (x - 1), ``RIGHT`` (x + 1); its
goal one-hot and auxiliary head list the colors in plane order. Its own picture of a board
(``ColorMaze.render``: ``np.flipud(grid.T)``) draws x to the right and y upward. This project's planes
are ``[red, green, blue, leader, follower]``, each indexed ``[row, col]`` with row 0 at the top, and its
actions move up, down, left, right on the screen. So a paper cell ``(x, y)`` is our ``(H - 1 - y, x)``:
a board turns by ``np.rot90`` (paper ``[x, y]`` -> our ``[row, col]``), the paper's actions keep their
names, and colors and planes are reordered by name, so that each of the paper's colors keeps its name
here (its blue is our blue).

Every conversion of the paper's observations, goals, cells and actions is here: the replay import of its
dumps (``colorgrid.replay.paper_dumps``) and the checkpoint import (``train.paper_code``, which turns its
weights with the same mapping) both read it.
"""

from __future__ import annotations

import numpy as np

from colorgrid.config import COLOR_NAMES
from colorgrid.env import ACTION_NAMES

PAPER_SOURCE = "andreyrisukhin/ColorGrid (run_ppo.py)"
"""The paper's released code, as imported files record where they came from."""
PAPER_PLANES = ("red", "blue", "green", "leader", "follower")
"""The paper code's planes (``color_maze.IDs``), in its order; its goal one-hot and auxiliary head list the
first three."""
PAPER_COLORS = PAPER_PLANES[:3]
"""The paper code's colors, in its order."""
PAPER_ACTIONS = ("up", "down", "left", "right")
"""The paper code's actions (``color_maze.Moves``: y + 1, y - 1, x - 1, x + 1), named as its picture shows them."""

OUR_PLANES = (*COLOR_NAMES[:len(PAPER_COLORS)], "leader", "follower")
PLANES_FROM_PAPER = [PAPER_PLANES.index(name) for name in OUR_PLANES]
"""Our plane ``k`` is the paper's plane ``PLANES_FROM_PAPER[k]``."""
COLORS_FROM_PAPER = PLANES_FROM_PAPER[:len(PAPER_COLORS)]
"""Our color ``k`` (goal one-hot column, auxiliary output) is the paper's color ``COLORS_FROM_PAPER[k]``."""
ACTIONS_FROM_PAPER = [PAPER_ACTIONS.index(name) for name in ACTION_NAMES[:len(PAPER_ACTIONS)]]
"""Our action ``a`` is the paper's action ``ACTIONS_FROM_PAPER[a]``."""


def board_from_paper(planes):
    """Boards indexed ``[..., x, y]`` to ``[..., row, col]``: ``ours[..., r, c] = paper[..., c, Y - 1 - r]``.
    A numpy array, or anything with a ``rot90(k, dims)`` method (a torch tensor: weights turn the same way)."""
    if isinstance(planes, np.ndarray):
        return np.rot90(planes, 1, axes=(-2, -1))
    return planes.rot90(1, (-2, -1))


def observation_from_paper(planes: np.ndarray) -> np.ndarray:
    """The paper's observations ``[..., 5, X, Y]`` (0/1, any dtype) as ours, ``[..., 5, H, W]`` uint8."""
    planes = np.asarray(planes)
    if planes.ndim < 3 or planes.shape[-3] != len(PAPER_PLANES):
        raise ValueError(f"the paper's observations have {len(PAPER_PLANES)} planes {list(PAPER_PLANES)}, "
                         f"got shape {list(planes.shape)}")
    if not np.isin(planes, (0, 1)).all():
        raise ValueError("the paper's observations hold only 0s and 1s (a cell holds a block or an agent, or not)")
    return np.ascontiguousarray(board_from_paper(planes[..., PLANES_FROM_PAPER, :, :])).astype(np.uint8)


def colors_from_paper(values: np.ndarray) -> np.ndarray:
    """Anything with one column per color in the paper's order (goal one-hots, auxiliary logits), ``[..., 3]``,
    in ours."""
    return np.asarray(values)[..., COLORS_FROM_PAPER]


def action_values_from_paper(values: np.ndarray) -> np.ndarray:
    """One column per action in the paper's order (its logits), ``[..., 4]``, in ours."""
    return np.asarray(values)[..., ACTIONS_FROM_PAPER]


def actions_from_paper(actions: np.ndarray) -> np.ndarray:
    """The paper's action indices as ours (the same moves)."""
    return np.argsort(ACTIONS_FROM_PAPER)[np.asarray(actions)]


def cells_from_paper(xy: np.ndarray, height: int) -> np.ndarray:
    """Positions ``[..., 2]`` as the paper's env holds them, ``(x, y)``, to our ``(row, col)``."""
    xy = np.asarray(xy)
    return np.stack([height - 1 - xy[..., 1], xy[..., 0]], axis=-1)
