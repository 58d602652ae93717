"""Headless GIF/MP4 export of replays: the board plus a side panel of scores and beliefs.

The panel names every agent of the team (1:1: ``leader``, ``follower``; else by label and name,
``L1 (leader_0)``), draws one belief chart per agent that logged goal probabilities, and a
timeline with one row of pickup ticks per agent.

No display or browser: frames come from ``colorgrid.render``, GIFs are written by Pillow (in
the core), MP4s by imageio with imageio-ffmpeg, which carries its own ffmpeg binary (the
``video`` extra: 165 MB installed, so the core leaves it out).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from colorgrid.config import EnvConfig
from colorgrid.extras import require
from colorgrid.render import PALETTE, _font, render_rgb
from colorgrid.roles import scores
from colorgrid.files import atomic_path
from colorgrid.replay import Replay, replay_states

FORMATS = ("gif", "mp4")
PANEL_WIDTH = 230
PANEL_BG = (250, 250, 247)
INK = (30, 30, 30)
GOOD, BAD = (30, 140, 60), (200, 40, 40)
LINE = 15  # one line of small text
BAR = 16  # one belief bar
TIMELINE_TOP = 30  # the timeline's cursor and goal strip, above its rows of pickup ticks
TICK_ROW = 5  # one agent's row of pickup ticks


def _rgb(color_index: int) -> tuple[int, int, int]:
    return tuple(int(v) for v in PALETTE[color_index])


def agent_label(config: EnvConfig, agent: int) -> str:
    """How the panel names agent ``agent``: its name in the 1:1 team (``leader``, ``follower``), else its
    label and name (``L1 (leader_0)``), as the board marks it."""
    name = config.agent_names[agent]
    return name if config.one_to_one else f"{config.symbols[agent]} ({name})"


def believers(replay: Replay) -> list[int]:
    """The agents that logged goal probabilities, in index order: one belief chart each."""
    return [i for i, name in enumerate(replay.config.agent_names) if replay.goal_probs.get(name) is not None]


def timeline_height(num_agents: int) -> int:
    """Pixels at the panel's foot for the episode timeline: cursor, goal strip, one row of ticks per agent."""
    return TIMELINE_TOP + TICK_ROW * num_agents


def panel_height(replay: Replay) -> int:
    """The least panel height that holds every line at every step (a frame is at least this tall)."""
    cfg, A = replay.config, replay.config.num_agents
    height = 8 + 22  # step
    if replay.block_reward is not None:
        height += 18 + LINE * A  # team, then each agent
    height += 6 + 24  # true goal
    height += len(believers(replay)) * (16 + BAR * cfg.num_colors + 6)
    if replay.picked_color is not None:
        height += LINE * (A + 1)  # the last step's pickups, and a goal switch
    return height + timeline_height(A)


def draw_panel(replay: Replay, t: int, state, height: int) -> np.ndarray:
    """[height, PANEL_WIDTH, 3] uint8: step, every agent's score, true goal, one belief chart per agent
    with goal probabilities, the last step's events and a timeline."""
    cfg = replay.config
    img = Image.new("RGB", (PANEL_WIDTH, height), PANEL_BG)
    draw = ImageDraw.Draw(img)
    font, small = _font(14), _font(11)
    x, y = 10, 8
    draw.text((x, y), f"step {t} / {cfg.horizon}", fill=INK, font=font)
    y += 22
    if replay.block_reward is not None:
        score = scores(state, cfg)
        draw.text((x, y), f"team {score['team']:+g}", fill=INK, font=font)
        y += 18
        for i, name in enumerate(cfg.agent_names):
            draw.text((x, y), f"{agent_label(cfg, i)} {score[name]:+g}", fill=INK, font=small)
            y += LINE
    goal = int(state.goal[0])
    y += 6
    draw.text((x, y), "true goal", fill=INK, font=small)
    draw.rectangle([x + 70, y, x + 84, y + 13], fill=_rgb(goal))
    draw.text((x + 90, y), cfg.color_names[goal], fill=INK, font=small)
    y += 24
    belief_t = min(t, replay.num_steps - 1)
    for i in believers(replay):
        probs = replay.goal_probs[cfg.agent_names[i]]
        draw.text((x, y), f"{agent_label(cfg, i)} belief", fill=INK, font=small)
        y += 16
        for k, p in enumerate(probs[belief_t]):
            draw.rectangle([x, y, x + 150, y + 11], outline=(200, 200, 200))
            draw.rectangle([x, y, x + int(150 * p), y + 11], fill=_rgb(k))
            draw.text((x + 156, y - 1), f"{p:.2f}", fill=INK, font=small)
            y += BAR
        y += 6
    if t > 0 and replay.picked_color is not None:
        for i in range(cfg.num_agents):
            c = replay.picked_color[t - 1][i]
            if c >= 0:
                ok = c == replay.goal[t - 1]
                draw.text((x, y), f"{agent_label(cfg, i)} took {cfg.color_names[c]} {'+' if ok else '-'}",
                          fill=GOOD if ok else BAD, font=small)
                y += LINE
        if replay.goal_switched[t - 1]:
            draw.text((x, y), f"goal switched -> {cfg.color_names[goal]}", fill=(120, 60, 160), font=small)
    _draw_timeline(draw, replay, t, height)
    return np.asarray(img)


def _draw_timeline(draw: ImageDraw.ImageDraw, replay: Replay, t: int, height: int) -> None:
    """A strip of the whole episode: goal color per step, pickup ticks (one row per agent, in index order:
    the leaders' on top), switch marks, a cursor."""
    x0, x1, y0 = 10, PANEL_WIDTH - 10, height - timeline_height(replay.config.num_agents)
    T = replay.num_steps
    span = x1 - x0
    for s in range(T):
        xa, xb = x0 + span * s // T, x0 + span * (s + 1) // T
        draw.rectangle([xa, y0 + 10, max(xa, xb - 1), y0 + 18], fill=_rgb(replay.goal[s]))
        if replay.picked_color is not None:
            for i in range(replay.config.num_agents):
                c = replay.picked_color[s][i]
                if c >= 0:
                    color = GOOD if c == replay.goal[s] else BAD
                    draw.line([xa, y0 + 20 + TICK_ROW * i, xa, y0 + 24 + TICK_ROW * i], fill=color)
            if replay.goal_switched[s]:
                draw.line([xb, y0 + 4, xb, y0 + 9], fill=(120, 60, 160), width=2)
    cx = x0 + span * min(t, T) // T
    draw.polygon([(cx - 4, y0), (cx + 4, y0), (cx, y0 + 8)], fill=INK)


def episode_frames(replay: Replay, cell: int = 12, start: int = 0, end: int | None = None, path=None):
    """Yield the RGB frames of steps ``start..end`` (inclusive) of a replay: the board, and the panel beside it.

    A frame is as tall as the board, or as the panel when its lines need more (large teams, small boards):
    the board then stands on the panel's background.
    """
    states = replay_states(replay, path)
    last = len(states) - 1
    end = last if end is None else end
    if not 0 <= start <= end <= last:
        raise ValueError(f"--start/--end must satisfy 0 <= start <= end <= {last}, got {start}..{end}")
    needed = panel_height(replay)
    for t in range(start, end + 1):
        board = render_rgb(states[t], replay.config, cell=cell)
        height = max(board.shape[0], needed)
        if height > board.shape[0]:
            board = np.concatenate([board, np.full((height - board.shape[0], *board.shape[1:]), PANEL_BG,
                                                   dtype=np.uint8)])
        panel = draw_panel(replay, t, states[t], height)
        frame = np.concatenate([board, panel], axis=1)
        pad_h, pad_w = (-frame.shape[0]) % 2, (-frame.shape[1]) % 2  # even sizes for yuv420p video
        if pad_h or pad_w:
            frame = np.pad(frame, ((0, pad_h), (0, pad_w), (0, 0)), constant_values=255)
        yield frame


def export(replay: Replay, out: str | os.PathLike, fmt: str, fps: float = 8.0, cell: int = 12,
           start: int = 0, end: int | None = None, path=None) -> Path:
    """Write the replay as a GIF or MP4 at ``out`` (atomically); returns the path. An MP4 needs the ``video``
    extra (``MissingExtra`` without it)."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; choose one of {list(FORMATS)}")
    if fmt == "mp4":
        require("video", "MP4 export")
    if not fps > 0:
        raise ValueError(f"--fps must be > 0, got {fps}")
    if not 4 <= cell <= 64:
        raise ValueError(f"--scale (pixels per cell) must be in [4, 64], got {cell}")
    out = Path(out)
    with atomic_path(out) as tmp:
        frames = episode_frames(replay, cell, start, end, path)
        if fmt == "gif":
            images = gif_frames(list(frames))
            images[0].save(tmp, save_all=True, append_images=images[1:], duration=int(round(1000 / fps)),
                           loop=0, optimize=False)
        else:
            import imageio.v2 as imageio

            with imageio.get_writer(tmp, format="FFMPEG", mode="I", fps=fps, codec="libx264",
                                    pixelformat="yuv420p", macro_block_size=2, quality=7) as writer:
                for f in frames:
                    writer.append_data(f)
    return out


def gif_frames(frames: list[np.ndarray]) -> list[Image.Image]:
    """Palette images sharing one palette, built from a montage of sampled frames.

    One shared palette is ~10x faster than quantizing every frame on its own and
    keeps colors stable from frame to frame.
    """
    picks = sorted({0, len(frames) // 3, 2 * len(frames) // 3, len(frames) - 1})
    montage = Image.fromarray(np.concatenate([frames[i] for i in picks], axis=0))
    palette = montage.quantize(colors=255, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
    return [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]


def default_output(replay_path: Path, fmt: str) -> Path:
    """Where a replay is exported without ``--out``: in the current folder, named after the replay
    (``astar+bayes_seed2026.gif``), never beside it: a released replay lies inside the installed package."""
    name = replay_path.name
    stem = name[: -len(".replay.json")] if name.endswith(".replay.json") else replay_path.stem
    return Path(f"{stem}.{fmt}")


__all__ = ["FORMATS", "agent_label", "believers", "default_output", "draw_panel", "episode_frames", "export",
           "panel_height"]
