"""The picture of the board on a study's instructions page (``web/study_board.png``), drawn by the renderer
(``colorgrid.render``) and labelled in a participant's words: which disc is theirs, which their AI partner's,
what the frame and the blocks mean.

The picture is committed; after a change to the renderer's colors, draw it again::

    python -m server.study.picture            # writes web/study_board.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from colorgrid.config import EnvConfig
from colorgrid.env import BatchEnv
from colorgrid.render import PALETTE, _font, render_grid, tiles

OUT = Path(__file__).resolve().parents[2] / "web" / "study_board.png"
SIZE = (600, 392)
"""The picture's width and height in pixels (the instructions card shows it at this size or smaller)."""
CELL = 11
"""Pixels per cell of the board."""
FRAME = 11
"""The goal frame's width in pixels (the study page's frame, in proportion to its cells)."""
BOARD_AT = (6, 6)
"""Where the framed board's top left corner is."""
GOAL = 2
"""The goal color of the picture (blue)."""
AGENT_AT = ((9, 11), (15, 19))
"""The leader's and the follower's (row, column): near each other, away from the frame."""
TILE = 30
"""Pixels per cell of the discs and blocks drawn large in the labels."""
LABELS_X = 392
BACKGROUND = (255, 255, 255)
INK = (34, 34, 34)
POINTER = (40, 44, 52)


def board_state(config: EnvConfig):
    """A board of the default setting with the agents at ``AGENT_AT`` and the goal ``GOAL``."""
    env = BatchEnv(config, num_envs=1, seed=2026)
    env.reset()
    state = env.state
    state.agent_cell[0] = [row * config.width + col for row, col in AGENT_AT]
    state.goal[0] = GOAL
    return state


def board_picture() -> tuple[np.ndarray, dict[str, tuple[int, int]]]:
    """The labelled picture ``[H, W, 3]`` uint8, and where its parts are (``x, y`` of a pixel inside each):
    ``frame``, ``leader`` and ``follower`` (their discs on the board), ``leader_label`` and ``follower_label``
    (the large discs beside the words), ``goal_label`` (the goal swatch)."""
    config = EnvConfig()
    state = board_state(config)
    grid = render_grid(state, config, cell=CELL)
    side = grid.shape[0] + 2 * FRAME
    image = Image.new("RGB", SIZE, BACKGROUND)
    framed = np.empty((side, side, 3), dtype=np.uint8)
    framed[:] = PALETTE[GOAL]
    framed[FRAME:FRAME + grid.shape[0], FRAME:FRAME + grid.shape[1]] = grid
    image.paste(Image.fromarray(framed), BOARD_AT)
    draw = ImageDraw.Draw(image)
    font, small = _font(16), _font(13)
    big = tiles(config, TILE)  # floor, one per color, one per agent
    x0, y0 = BOARD_AT

    def centre(row: int, col: int) -> tuple[int, int]:
        return x0 + FRAME + col * CELL + CELL // 2, y0 + FRAME + row * CELL + CELL // 2

    places = {"frame": (x0 + FRAME // 2, y0 + side // 2)}
    rows = [(40, "you", "You", ["the dark disc marked L"]),
            (125, "partner", "Your AI partner", ["the yellow disc marked F:", "it does not know the goal"]),
            (215, "goal", "The goal color", ["the frame around the board:", "collect these blocks, +1"]),
            (305, "other", "Other colors", ["blocks of another color", "cost your team 1"])]
    for y, what, title, words in rows:
        if what in ("you", "partner"):
            agent = 0 if what == "you" else 1
            tile = big[1 + config.num_colors + agent]
            at = centre(*AGENT_AT[agent])
            places["leader" if agent == 0 else "follower"] = at
            places[("leader" if agent == 0 else "follower") + "_label"] = (LABELS_X + TILE // 2, y + TILE // 2)
            radius = CELL
            draw.ellipse([at[0] - radius, at[1] - radius, at[0] + radius, at[1] + radius], outline=POINTER, width=2)
            target = (at[0] + radius, at[1])
        elif what == "goal":
            tile = np.empty((TILE, TILE, 3), dtype=np.uint8)
            tile[:] = PALETTE[GOAL]
            places["goal_label"] = (LABELS_X + TILE // 2, y + TILE // 2)
            target = (x0 + side - FRAME // 2, y + TILE // 2)
        else:
            tile = np.concatenate([big[1 + k][:, :TILE // 2] for k in range(config.num_colors) if k != GOAL], axis=1)
            target = None
        image.paste(Image.fromarray(tile), (LABELS_X, y))
        draw.text((LABELS_X + TILE + 8, y), title, fill=INK, font=font)
        for i, line in enumerate(words):
            draw.text((LABELS_X + TILE + 8, y + 21 + 16 * i), line, fill=INK, font=small)
        if target is not None:
            draw.line([target, (LABELS_X - 6, y + TILE // 2)], fill=POINTER, width=2)
            draw.ellipse([LABELS_X - 9, y + TILE // 2 - 3, LABELS_X - 3, y + TILE // 2 + 3], fill=POINTER)
    return np.asarray(image), places


def main(argv: list[str]) -> int:
    out = Path(argv[0]) if argv else OUT
    Image.fromarray(board_picture()[0]).save(out, optimize=True)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
