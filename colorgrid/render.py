"""Pictures of one environment: an RGB frame and an ANSI text view.

Rendering is a pure function of a state (a batch of one, or one env of a
batch picked by ``index``). It is separate from observations: the network sees
0/1 planes, a person sees this. The replay exporter, the play server and the
tests all draw through here.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from colorgrid.config import EnvConfig
from colorgrid.roles import scores
from colorgrid.state import EnvState

# RGB per block color, in the order of ``config.COLOR_NAMES``.
PALETTE = np.array(
    [[220, 50, 47], [46, 160, 67], [38, 110, 220], [245, 145, 30],
     [140, 70, 190], [30, 190, 200], [140, 90, 50], [235, 110, 180]], dtype=np.uint8)
FLOOR = np.array([236, 236, 232], dtype=np.uint8)
GRID_LINE = np.array([210, 210, 204], dtype=np.uint8)
LEADER_RGB = np.array([25, 25, 25], dtype=np.uint8)
FOLLOWER_RGB = np.array([255, 200, 0], dtype=np.uint8)
"""The followers' yellow: no block color is yellow, and it stands out from the light floor and the dark leader."""
LABEL_LIGHT = np.array([255, 255, 255], dtype=np.uint8)
AGENT_COLORS = {"leader": (LEADER_RGB, LABEL_LIGHT), "follower": (FOLLOWER_RGB, LEADER_RGB)}
"""``(body, ink)`` per role: dark leaders with a white label, yellow followers with a dark one."""
HEADER_BG = np.array([40, 44, 52], dtype=np.uint8)
HEADER_HEIGHT = 22
GOAL_BORDER = 4


def hex_color(rgb) -> str:
    """``[r, g, b]`` -> ``"#rrggbb"``."""
    return "#%02x%02x%02x" % tuple(int(v) for v in rgb)


def look(config: EnvConfig | None = None) -> dict:
    """How the pictures look, as hex colors for pages that draw boards themselves (the play server's and
    the replay player's): ``palette`` (one per block color: the config's colors, or every color),
    ``floor``, ``grid`` (cell lines) and ``agents``, in index order: ``{name, role, symbol, body, ink}``
    (the 1:1 team's when no config is given)."""
    num_colors = len(PALETTE) if config is None else config.num_colors
    config = config if config is not None else EnvConfig()
    return {
        "palette": [hex_color(rgb) for rgb in PALETTE[:num_colors]],
        "floor": hex_color(FLOOR), "grid": hex_color(GRID_LINE),
        "agents": [{"name": name, "role": role, "symbol": symbol, "body": hex_color(AGENT_COLORS[role][0]),
                    "ink": hex_color(AGENT_COLORS[role][1])}
                   for name, role, symbol in zip(config.agent_names, config.roles, config.symbols)],
    }


def tiles(config: EnvConfig, cell: int) -> np.ndarray:
    """[1 + num_colors + A, cell, cell, 3] uint8 tiles: floor, one per block color, one per agent (its label
    on its role's colors)."""
    return _tiles(config.num_colors, cell, config.symbols, config.roles)


@lru_cache(maxsize=16)
def _tiles(num_colors: int, cell: int, symbols: tuple[str, ...], roles: tuple[str, ...]) -> np.ndarray:
    out = np.empty((1 + num_colors + len(symbols), cell, cell, 3), dtype=np.uint8)
    out[:] = FLOOR
    out[:, -1, :] = GRID_LINE
    out[:, :, -1] = GRID_LINE
    margin = max(1, cell // 8)
    for k in range(num_colors):
        out[1 + k, margin:cell - margin - 1, margin:cell - margin - 1] = PALETTE[k]
    for i, (letter, role) in enumerate(zip(symbols, roles)):
        font = _font(max(8, (cell - 4) * 2 // (len(letter) + 1)))  # two-character labels in a smaller size
        body, ink = AGENT_COLORS[role]
        img = Image.fromarray(out[num_colors + 1 + i])
        draw = ImageDraw.Draw(img)
        draw.ellipse([0, 0, cell - 2, cell - 2], fill=tuple(int(v) for v in body), outline=(0, 0, 0))
        draw.text(((cell - 1) / 2, (cell - 1) / 2), letter, fill=tuple(int(v) for v in ink), font=font, anchor="mm")
        out[num_colors + 1 + i] = np.asarray(img)
    return out


@lru_cache(maxsize=8)
def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow without FreeType sizes
        return ImageFont.load_default()


def cell_ids(state: EnvState, config: EnvConfig, index: int = 0) -> np.ndarray:
    """[H, W] int: tile id per cell (0 floor, 1 + color for blocks, then one per agent in index order)."""
    ids = state.block_colors(config)[index] + 1
    rows, cols = np.divmod(state.agent_cell[index], config.width)
    ids[rows, cols] = config.num_colors + 1 + np.arange(config.num_agents)
    return ids


def render_grid(state: EnvState, config: EnvConfig, index: int = 0, cell: int = 16) -> np.ndarray:
    """[H*cell, W*cell, 3] uint8: the board alone, from a tile cache."""
    ids = cell_ids(state, config, index)
    board = tiles(config, cell)[ids]  # [H, W, cell, cell, 3]
    return board.transpose(0, 2, 1, 3, 4).reshape(config.height * cell, config.width * cell, 3)


def render_rgb(state: EnvState, config: EnvConfig, index: int = 0, cell: int = 16) -> np.ndarray:
    """[HEADER + H*cell + 2*border, W*cell + 2*border, 3] uint8: board framed in the goal color.

    The header names the step, the goal color (with a swatch) and the team score;
    the frame around the board is the goal color, so it reads at a glance.
    """
    board = render_grid(state, config, index, cell)
    goal = int(state.goal[index])
    b = GOAL_BORDER
    h, w = board.shape[:2]
    frame = np.empty((HEADER_HEIGHT + h + 2 * b, w + 2 * b, 3), dtype=np.uint8)
    frame[:HEADER_HEIGHT] = HEADER_BG
    frame[HEADER_HEIGHT:] = PALETTE[goal]
    frame[HEADER_HEIGHT + b:HEADER_HEIGHT + b + h, b:b + w] = board
    img = Image.fromarray(frame[:HEADER_HEIGHT])
    draw = ImageDraw.Draw(img)
    font = _font(13)
    draw.rectangle([6, 5, 18, 17], fill=tuple(int(v) for v in PALETTE[goal]))
    team = scores(state, config, index)["team"]
    text = f"goal {config.color_names[goal]}   step {int(state.t[index])}/{config.horizon}   team {team:+g}"
    draw.text((24, 4), text, fill=(255, 255, 255), font=font)
    frame[:HEADER_HEIGHT] = np.asarray(img)
    return frame


_ANSI_COLOR = ("31", "32", "34", "33", "35", "36", "33", "95")


def render_ansi(state: EnvState, config: EnvConfig, index: int = 0, color: bool = True) -> str:
    """Text view: one character per cell (``.`` floor, color initial for blocks, ``config.symbols`` for agents);
    in teams other than 1:1 two characters per cell, as their labels have two (``L1``, ``F2``)."""
    ids = cell_ids(state, config, index)
    width = max(len(symbol) for symbol in config.symbols)
    symbols = ["."] + [name[0] for name in config.color_names] + list(config.symbols)
    symbols = [symbol.ljust(width) for symbol in symbols]
    if color:
        symbols = ([f"\x1b[2m{symbols[0]}\x1b[0m"]
                   + [f"\x1b[{_ANSI_COLOR[k]}m{symbols[1 + k]}\x1b[0m" for k in range(config.num_colors)]
                   + [f"\x1b[1;7m{letter}\x1b[0m" for letter in symbols[1 + config.num_colors:]])
    goal = config.color_names[int(state.goal[index])]
    score = scores(state, config, index)
    agents = " ".join(f"{name} {score[name]:+g}" for name in config.agent_names)
    lines = [f"step {int(state.t[index])}/{config.horizon}  goal {goal}  {agents}"]
    lines += [" ".join(symbols[v] for v in row) for row in ids]
    return "\n".join(lines)
