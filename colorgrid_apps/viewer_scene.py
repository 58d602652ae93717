"""The 3D replay viewer's scene and panel: a replay's meshes in a viser scene (``GridScene``), the step's summary and
the followers' belief charts as the live panel shows them, and the same panel drawn into the scene for the export
(``ScenePanel``)."""

from __future__ import annotations

import numpy as np
import viser
import viser.uplot

from colorgrid.enums import Role
from colorgrid.render import AGENT_COLORS, FLOOR, GRID_LINE, PALETTE
from colorgrid_apps.viewer_frames import (HIDDEN_Z, Frame, agent_label, believer_label, block_capacity, board_bounds,
                                          frame_at, team, unit_cube)

INK = (60, 60, 60)  # the scene chart's frame, ticks and cursor
CURSOR = "#202020"  # the live chart's cursor: darker and wider than any curve, and never in the legend


class GridScene:
    """The meshes of one replay in one scene (a tab's, or a recording's); ``show(t)`` moves them."""

    def __init__(self, scene, data: dict, root: str = "/grid"):
        self.scene, self.data, self.root = scene, data, root
        H, W = data["height"], data["width"]
        self.capacity = block_capacity(data)
        self.goal_plate = scene.add_box(f"{root}/goal", dimensions=(W + 1.0, H + 1.0, 0.1),
                                        position=(W / 2, H / 2, -0.12), color=(150, 150, 150))
        scene.add_box(f"{root}/floor", dimensions=(float(W), float(H), 0.1), position=(W / 2, H / 2, -0.05),
                      color=tuple(int(x) for x in FLOOR))
        verts, faces = unit_cube()
        first = frame_at(data, 0, self.capacity)
        self.blocks = []
        for k, cap in enumerate(self.capacity):
            n = max(cap, 1)
            pos = first.block_positions[k] if cap else np.full((1, 3), HIDDEN_Z, dtype=np.float32)
            self.blocks.append(scene.add_batched_meshes_simple(
                f"{root}/blocks/{data['colors'][k]}", verts * 0.8, faces,
                batched_wxyzs=np.tile(np.array([1.0, 0, 0, 0], dtype=np.float32), (n, 1)),
                batched_positions=pos, batched_colors=tuple(int(x) for x in PALETTE[k])))
        self.agents = {}  # name -> sphere, in index order
        self.labels = {}  # name -> the label over it
        for i, agent in enumerate(data["look"]["agents"]):
            name = agent["name"]
            body = np.minimum(AGENT_COLORS[agent["role"]][0], 235)  # pure white glares under the scene's light
            self.agents[name] = scene.add_icosphere(f"{root}/{name}", radius=0.45, position=first.agents[i],
                                                    color=tuple(int(x) for x in body))
            self.labels[name] = scene.add_label(f"{root}/{name}/label", agent_label(agent), position=(0.0, 0.0, 0.8))
        self.show(0)

    def show(self, t: int) -> Frame:
        frame = frame_at(self.data, t, self.capacity)
        for k, handle in enumerate(self.blocks):
            if self.capacity[k]:
                handle.batched_positions = frame.block_positions[k]
        for handle, position in zip(self.agents.values(), frame.agents):
            handle.position = position
        self.goal_plate.color = tuple(int(x) for x in PALETTE[frame.goal])
        return frame

    def remove(self) -> None:
        for handle in (self.goal_plate, *self.blocks, *self.agents.values()):
            handle.remove()



def step_summary(data: dict, t: int, strong=str) -> list[str]:
    """The panel's lines at step ``t``: step, goal, scores, each follower's beliefs; ``strong`` marks the key values.

    Agents are named as the board labels them: by name in the 1:1 team, by symbol in others."""
    board = data["boards"][t]
    lines = [f"step {strong(t)} / {data['steps']}", f"goal: {strong(data['colors'][board['goal']])}"]
    scores = board["scores"]
    if scores is not None:
        key = "name" if team(data).one_to_one else "symbol"
        names = [agent[key] for agent in data["look"]["agents"]]
        each = ", ".join(f"{name} {score:+.0f}" for name, score in zip(names, scores))
        lines.append(f"team {strong(f'{sum(scores):+.0f}')} ({each})")
    for name in believers(data):
        row = beliefs(data, name)[min(t, data["steps"] - 1)]
        lines.append(f"{believer_label(data, name)} believes: "
                     + ", ".join(f"{c} {p:.2f}" for c, p in zip(data["colors"], row)))
    return lines


def chart_title(data: dict, name: str) -> str:
    """The title of follower ``name``'s belief chart: ``follower's goal probabilities`` in the 1:1 team."""
    return f"{believer_label(data, name)}'s goal probabilities"


def believers(data: dict) -> list[str]:
    """The followers that logged goal probabilities, in index order: one chart each."""
    probs = data.get("goal_probs", {})
    return [agent["name"] for agent in data["look"]["agents"]
            if agent["role"] == Role.FOLLOWER and probs.get(agent["name"])]


def beliefs(data: dict, name: str) -> np.ndarray | None:
    """Agent ``name``'s goal probabilities, ``[T, colors]`` (one row per action), or None if it logged none."""
    probs = data.get("goal_probs", {}).get(name)
    return np.asarray(probs, dtype=np.float64) if probs else None


def belief_series(data: dict, name: str) -> tuple[tuple[np.ndarray, ...] | None, tuple]:
    """uPlot data and series of ``name``'s belief chart; ``(None, ())`` if it has no beliefs.

    x is every step ``0..steps``; then one probability curve per color, NaN past the last action (no belief
    there). The current step is not data: ``belief_axes`` draws it.
    """
    probs = beliefs(data, name)
    if probs is None:
        return None, ()
    x = np.arange(data["steps"] + 1, dtype=np.float64)
    curves = np.full((len(x), probs.shape[1]), np.nan)
    curves[: len(probs)] = probs
    series = (viser.uplot.Series(label="step"),
              *(viser.uplot.Series(label=name, stroke=data["look"]["palette"][k], width=2)
                for k, name in enumerate(data["colors"])))
    return (x, *curves.T), series


def belief_axes(t: int) -> tuple[dict, ...]:
    """The belief chart's axes at step ``t``: x in steps (below), y a probability, and the cursor: an axis on the
    x scale above the plot whose one tick, labelled ``step t``, draws its grid line across the plot at ``t``."""
    cursor = viser.uplot.Axis(scale="x", side=0, splits=(float(t),), values=(f"step {t}",), stroke=CURSOR, size=24,
                              grid=viser.uplot.Axis_Grid(show=True, stroke=CURSOR, width=2.0),
                              ticks=viser.uplot.Axis_Ticks(show=True, stroke=CURSOR, width=2.0, size=6))
    return {"label": "step"}, {}, cursor


def belief_scales(data: dict) -> dict[str, viser.uplot.Scale]:
    """x in plain steps (uPlot reads x as unix time unless ``time`` is off), y a probability."""
    return {"x": viser.uplot.Scale(time=False, range=(0.0, float(data["steps"]))),
            "y": viser.uplot.Scale(range=(0.0, 1.0))}


class ScenePanel:
    """The panel's lines and the belief charts drawn into the scene, right of the board, for recordings.

    A recording keeps scene messages but no GUI, so the export shows its panel this way: a text
    label rewritten per step, and per follower with beliefs a chart (the first beside the board,
    the others below it): the curves as line segments, and a cursor moved to the current step.
    """

    CHART_GAP = 6.0  # between one chart's plotting area and the next one's, below it (room for ticks and legend)

    def __init__(self, scene, data: dict, title: str, root: str = "/panel"):
        self.data, self.title = data, title
        H, W, steps = data["height"], data["width"], data["steps"]
        self.x0, self.width, self.height = W + 4.5, float(W), H / 2  # each chart's plotting area, from (x0, its y0)
        self.facts = scene.add_label(f"{root}/facts", "", position=(self.x0 - 1.0, H + 0.5, 0.0))
        self.cursors = []  # (cursor, y0) per chart
        names = believers(data)
        for j, name in enumerate(names):
            where = f"{root}/chart" if team(data).one_to_one else f"{root}/chart/{name}"
            y0 = 0.0 - j * (self.height + self.CHART_GAP)
            self._draw_chart(scene, where, beliefs(data, name), steps, y0, chart_title(data, name))
        self.num_charts = len(names)
        self.show(0)

    def _draw_chart(self, scene, root: str, probs: np.ndarray, steps: int, y0: float, title: str) -> None:
        x0, w, h = self.x0, self.width, self.height
        scene.add_box(f"{root}/paper", dimensions=(w + 5.0, h + 5.0, 0.1),
                      position=(x0 + w / 2 - 1.0, y0 + h / 2 + 0.5, -0.05), color=tuple(int(c) for c in FLOOR))
        frame = np.array([[(0, 0), (w, 0)], [(w, 0), (w, h)], [(w, h), (0, h)], [(0, h), (0, 0)]], dtype=np.float32)
        scene.add_line_segments(f"{root}/frame", lift(frame, x0, y0), colors=INK, thickness=1.0,
                                thickness_units="screen")
        scene.add_line_segments(f"{root}/half", lift(np.array([[(0, h / 2), (w, h / 2)]], dtype=np.float32), x0, y0),
                                colors=tuple(int(c) for c in GRID_LINE), thickness=1.0, thickness_units="screen")
        xs = w * np.arange(len(probs)) / steps
        colors = self.data["colors"]
        for k, name in enumerate(colors):
            rgb = tuple(int(c) for c in PALETTE[k])
            points = np.stack([xs, h * probs[:, k]], axis=1).astype(np.float32)
            scene.add_line_segments(f"{root}/{name}", lift(np.stack([points[:-1], points[1:]], axis=1), x0, y0),
                                    colors=rgb, thickness=2.5, thickness_units="screen")
            left = w * k / len(colors)  # the legend: a colored dash, then the name
            key = np.array([[(left, h + 1.2), (left + 1.5, h + 1.2)]], dtype=np.float32)
            scene.add_line_segments(f"{root}/key/{name}", lift(key, x0, y0), colors=rgb, thickness=4.0,
                                    thickness_units="screen")
            scene.add_label(f"{root}/key/{name}/label", name, position=(x0 + left + 2.0, y0 + h + 1.2, 0.0),
                            anchor="center-left")
        scene.add_label(f"{root}/title", title, position=(x0, y0 + h + 2.8, 0.0), anchor="center-left")
        for text, xy, anchor in (("0", (0, -0.6), "top-center"), (str(steps), (w, -0.6), "top-center"),
                                 ("step", (w / 2, -0.6), "top-center"), ("1", (-0.6, h), "center-right"),
                                 ("0.5", (-0.6, h / 2), "center-right"), ("0", (-0.6, 0), "center-right")):
            scene.add_label(f"{root}/ticks/{text}_{anchor}", text, position=(x0 + xy[0], y0 + xy[1], 0.0),
                            anchor=anchor)
        stroke = np.array([[(0, 0, 0.05), (0, h, 0.05)]], dtype=np.float32)  # moved along x by ``show``
        cursor = scene.add_line_segments(f"{root}/now", stroke, colors=INK, thickness=2.0, thickness_units="screen")
        self.cursors.append((cursor, y0))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The corners ``(lo, hi)`` of the box holding the board and this panel (what the export frames)."""
        lo, hi = board_bounds(self.data)
        bottom = -2.0 - max(0, self.num_charts - 1) * (self.height + self.CHART_GAP)
        return np.array([lo[0], bottom, lo[2]]), np.array([self.x0 + self.width + 1.5, hi[1], hi[2]])

    def show(self, t: int) -> None:
        self.facts.text = "\n".join([self.title, *step_summary(self.data, t)])
        for cursor, y0 in self.cursors:
            cursor.position = (self.x0 + self.width * t / self.data["steps"], y0, 0.0)


def lift(segments: np.ndarray, x0: float, y0: float = 0.0) -> np.ndarray:
    """2D chart segments ``[N, 2, 2]`` to scene segments ``[N, 2, 3]``, moved by ``(x0, y0)``, just above the paper."""
    out = np.zeros((*segments.shape[:2], 3), dtype=np.float32)
    out[..., :2] = segments
    out[..., 0] += x0
    out[..., 1] += y0
    out[..., 2] = 0.02
    return out


