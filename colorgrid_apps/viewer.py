"""The 3D replay viewer (``colorgrid view [PATH]``): every viser call of the project lives in this module.

A viser server on 127.0.0.1 shows a replay's grid as batched meshes (floor, one batch of
cubes per block color, every agent of the team in its role's color with a label, ``L (leader)``
in the 1:1 team, ``L1 (leader_0)``, ``F2 (follower_1)``, ... in others), with a per-tab panel: a
dropdown of the replays in a folder, a step slider, play/pause and speed, step/scores/goal, and one
uPlot chart of goal probabilities per follower that logged them (x in steps, a cursor at the
current step: a vertical line labelled with the step, drawn by an axis of its own, not a series). The team comes from the replay (its timeline's ``look``), never from constants.
Each tab gets its own scene, controls and camera, which opens framing the whole board.

``standalone_html`` records a replay into an offline HTML file (the viser client with the
scene embedded). A recording holds scene messages only, never GUI ones, so the export draws
the panel and the charts into the scene beside the board (``ScenePanel``), and plays one
recording second per step: its playback slider counts steps, and a counter of whole steps stands
in for viser's clock, which reads tenths of a second (``STEP_COUNTER``). The export button
sends that file to the browser; ``export_html`` writes it for ``--export``. viser is pinned in
``pyproject.toml``: client and server must match.
"""

from __future__ import annotations

import html
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rich
import viser
import viser.uplot

from colorgrid.config import EnvConfig
from colorgrid.render import AGENT_COLORS, FLOOR, GRID_LINE, PALETTE
from colorgrid.replay import ReplayError, load
from colorgrid.replay.timeline import timeline

SPEEDS = ("0.25", "0.5", "1", "2", "4", "8")
BASE_FPS = 8.0
HIDDEN_Z = -50.0  # where unused block instances wait
STEP_SECONDS = 1.0  # recording time per step: the export's slider and clock read in steps
FOV = np.deg2rad(50.0)  # vertical field of view of the opening camera
VIEW_FROM = np.array([0.0, -0.5, np.sqrt(3.0) / 2])  # look-at point to camera: from the south, 60 degrees up
WORLD_UP = np.array([0.0, 0.0, 1.0])  # viser's scene up direction (+z)
SQUARE = 1.0  # canvas aspect assumed before a tab reports its own: wider canvases see more
EXPORT_ASPECT = 4.0 / 3.0  # the export fills the window (no side panel), so it is rarely narrower
INK = (60, 60, 60)  # the scene chart's frame, ticks and cursor
CURSOR = "#202020"  # the live chart's cursor: darker and wider than any curve, and never in the legend


def unit_cube() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], dtype=np.float32)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.uint32)
    return v, f


@dataclass
class Frame:
    """The scene at one step, as arrays: what the meshes are set to (pure data, easy to test)."""

    block_positions: list  # per color: [N_k, 3] float32 (unused instances below the floor)
    agents: np.ndarray  # [A, 3] float32, in index order (the timeline's ``agent_names``)
    goal: int


def cell_xyz(cell: int, width: int, height: int, z: float) -> np.ndarray:
    """Cell index to scene coordinates: x to the right, y up the screen (row 0 at the top)."""
    r, c = divmod(int(cell), width)
    return np.array([c + 0.5, height - r - 0.5, z], dtype=np.float32)


def frame_at(data: dict, t: int, capacity: list[int]) -> Frame:
    H, W = data["height"], data["width"]
    board = data["boards"][t]
    colors = np.frombuffer(board["blocks"].encode(), dtype=np.uint8).astype(np.int64) - ord("0")  # '.' < 0
    cells = np.arange(H * W)
    positions = []
    for k, cap in enumerate(capacity):
        mine = cells[colors == k]
        pos = np.zeros((cap, 3), dtype=np.float32)
        pos[:, 2] = HIDDEN_Z
        pos[: len(mine), 0] = mine % W + 0.5
        pos[: len(mine), 1] = H - mine // W - 0.5
        pos[: len(mine), 2] = 0.4
        positions.append(pos)
    agents = np.stack([cell_xyz(board[agent["name"]], W, H, 0.45) for agent in data["look"]["agents"]])
    return Frame(positions, agents, board["goal"])


def team(data: dict) -> EnvConfig:
    """The replay's config (its team: ``agent_names``, ``roles``, ``symbols``, ``one_to_one``)."""
    return EnvConfig.from_dict(data["config"])


def agent_label(agent: dict) -> str:
    """The label over an agent (an entry of the timeline's ``look["agents"]``): ``L1 (leader_0)``, ``L (leader)``."""
    return f"{agent['symbol']} ({agent['name']})"


def believer_label(data: dict, name: str) -> str:
    """How the panel names a follower with beliefs: ``follower`` in the 1:1 team, else ``F1 (follower_0)``."""
    if team(data).one_to_one:
        return name
    return next(agent_label(agent) for agent in data["look"]["agents"] if agent["name"] == name)


def block_capacity(data: dict) -> list[int]:
    """Instances per color: the most blocks of that color on any step."""
    counts = np.zeros(len(data["colors"]), dtype=np.int64)
    for board in data["boards"]:
        codes = np.frombuffer(board["blocks"].encode(), dtype=np.uint8).astype(np.int64) - ord("0")
        counts = np.maximum(counts, np.bincount(codes[codes >= 0], minlength=len(counts)))
    return counts.tolist()


@dataclass(frozen=True)
class CameraPose:
    """Where a camera sits and looks, in viser's world coordinates (what ``aim`` hands to viser)."""

    position: np.ndarray  # [3]
    look_at: np.ndarray  # [3]
    up: np.ndarray  # [3] world up the camera keeps upright
    fov: float  # vertical field of view, radians


def board_bounds(data: dict) -> tuple[np.ndarray, np.ndarray]:
    """The corners ``(lo, hi)`` of the box holding the board: goal plate, floor, blocks and agents."""
    return np.array([-0.5, -0.5, -0.2]), np.array([data["width"] + 0.5, data["height"] + 0.5, 1.0])


def framing_camera(lo, hi, aspect: float = SQUARE, fov: float = FOV, margin: float = 1.08) -> CameraPose:
    """A camera looking from ``VIEW_FROM`` at the box ``lo``..``hi``, just far enough back to see all of it.

    A point is in view when, in camera coordinates, ``|right| <= depth * tan_h`` and ``|up| <= depth * tan_v``;
    the depth of a corner is the distance plus its offset along the view direction, which gives the
    closest distance for each of the eight corners in closed form. ``margin`` leaves a border around the box.
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    look_at = (lo + hi) / 2
    forward = -VIEW_FROM / np.linalg.norm(VIEW_FROM)
    right = np.cross(forward, WORLD_UP)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    tan_v = np.tan(fov / 2) / margin
    tan_h = aspect * tan_v
    offset = corners - look_at  # [8, 3]
    distance = np.max(np.maximum(np.abs(offset @ right) / tan_h, np.abs(offset @ up) / tan_v) - offset @ forward)
    return CameraPose(look_at - distance * forward, look_at, WORLD_UP.copy(), float(fov))


def aim(camera, pose: CameraPose) -> None:
    """Point a tab's camera (``client.camera``) or the one new tabs and recordings open with
    (``server.initial_camera``, also the target of the client's "reset view")."""
    camera.fov = pose.fov
    if isinstance(camera, viser.CameraHandle):
        camera.up_direction = pose.up
    else:
        camera.up = pose.up
    camera.position = pose.position  # a tab's camera carries its look-at along; set the look-at after
    camera.look_at = pose.look_at


def canvas_aspect(camera) -> float:
    """The aspect to frame a tab's canvas for: its reported width over height, at most ``SQUARE``.

    Capped because the canvas narrows just after connecting, when the control panel docks beside it.
    """
    try:
        return min(camera.aspect, SQUARE) if camera.image_height > 0 else SQUARE
    except AssertionError:  # no camera message from the browser yet
        return SQUARE


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


def load_timeline(path: Path) -> dict:
    """A verified replay's timeline, or a ValueError that says why it cannot be shown."""
    try:
        data = timeline(load(path), path)
    except ReplayError as err:
        raise ValueError(f"{path.name}: {err.problem}") from None
    if not data["verified"]:
        raise ValueError(f"{path.name} failed verification and is not shown: {data['problem']}")
    return data


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
            if agent["role"] == "follower" and probs.get(agent["name"])]


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


class TabView:
    """One browser tab: its own scene, controls, camera, playback state."""

    def __init__(self, viewer: "ReplayViewer", target, root: str = "/grid"):
        self.viewer, self.target, self.root = viewer, target, root
        gui = target.gui
        self.grid: GridScene | None = None
        self.data: dict | None = None
        self.charts: dict = {}  # follower name -> its belief chart (uPlot), in index order
        self.framed: tuple[int, int] | None = None  # the board size the camera was last aimed at
        self.playing = False
        self.next_tick = 0.0
        names = viewer.replay_names()
        self.dropdown = gui.add_dropdown("replay", options=names or ["(no replays found)"], initial_value=(names or ["(no replays found)"])[0])
        self.slider = gui.add_slider("step", min=0, max=1, step=1, initial_value=0)
        self.play_button = gui.add_button("play / pause")
        self.speed = gui.add_dropdown("speed", options=SPEEDS, initial_value="1")
        self.info = gui.add_markdown("")
        self.export_button = gui.add_button("export standalone HTML")
        self.export_note = gui.add_markdown("")
        self.dropdown.on_update(lambda _: self.open(self.dropdown.value))
        self.slider.on_update(lambda _: self.show(int(self.slider.value)))
        self.play_button.on_click(lambda _: self.toggle())
        self.export_button.on_click(lambda _: self.export())
        if names:
            self.open(names[0])
        else:
            self.info.content = f"No `*.replay.json` files in `{viewer.folder}`."

    def open(self, name: str) -> None:
        self.playing = False
        try:
            data = load_timeline(self.viewer.folder / name)
        except (ValueError, OSError) as err:
            self.info.content = f"**Cannot show this replay.** {err}"
            return
        if self.grid is not None:
            self.grid.remove()
        for chart in self.charts.values():
            chart.remove()
        self.charts = {}
        self.data, self.name = data, name
        self.grid = GridScene(self.target.scene, data, self.root)
        self.frame_board()
        self.slider.max = data["steps"]
        for name in believers(data):
            series_data, series = belief_series(data, name)
            self.charts[name] = self.target.gui.add_uplot(series_data, series, title=chart_title(data, name),
                                                          scales=belief_scales(data), axes=belief_axes(0),
                                                          aspect=2.0, padding=(10, 24, 0, 0))
        self.slider.value = 0
        self.show(0)

    @property
    def chart(self):
        """The first follower's belief chart (the 1:1 team's follower's), or None when no follower logged beliefs."""
        return next(iter(self.charts.values()), None)

    def frame_board(self) -> None:
        """Aim this tab's camera at the whole board, for its own canvas, when a new board size opens."""
        size = (self.data["width"], self.data["height"])
        if size == self.framed:
            return
        self.framed = size
        self.viewer.frame_new_tabs(self.data)
        if isinstance(self.target, viser.ClientHandle):
            camera = self.target.camera
            aim(camera, framing_camera(*board_bounds(self.data), aspect=canvas_aspect(camera)))

    def show(self, t: int) -> None:
        if self.data is None:
            return
        t = max(0, min(self.data["steps"], t))
        self.grid.show(t)
        self.info.content = "  \n".join([f"**{self.name}**", *step_summary(self.data, t, strong=lambda s: f"**{s}**")])
        for chart in self.charts.values():
            chart.axes = belief_axes(t)  # the cursor moves; the curves stay
        self.step = t

    def toggle(self) -> None:
        if self.data is None:
            return
        if not self.playing and self.step >= self.data["steps"]:
            self.slider.value = 0
        self.playing = not self.playing
        self.next_tick = time.monotonic()

    def tick(self, now: float) -> None:
        if not self.playing or now < self.next_tick:
            return
        self.next_tick = now + 1.0 / (BASE_FPS * float(self.speed.value))
        if self.step >= self.data["steps"]:
            self.playing = False
        else:
            self.slider.value = self.step + 1

    def export(self) -> None:
        """Send this replay as a standalone HTML file to the browser (nothing is written on the server's disk)."""
        if self.data is None:
            return
        filename = Path(self.name).name.removesuffix(".replay.json") + ".html"
        self.export_note.content = f"preparing `{filename}`..."
        page = standalone_html(self.data, Path(self.name).name)
        self.target.send_file_download(filename, page.encode(), save_immediately=True)
        self.export_note.content = f"sent `{filename}` to the browser"


class ReplayViewer:
    """The viser server; one ``TabView`` per connected tab, and a thread that advances playing tabs."""

    def __init__(self, folder: str | Path, host: str = "127.0.0.1", port: int = 8080):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FileNotFoundError(f"{self.folder} is not a folder of replays")
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.gui.configure_theme(show_share_button=False, control_width="large")
        self.server.gui.main_panel.dock_right()  # beside the canvas, not over it: the camera frames what is visible
        self.views: dict[int, TabView] = {}
        self.lock = threading.Lock()
        self.new_tab_board: tuple[int, int] | None = None  # the board size new tabs open framing
        names = self.replay_names()
        if names:  # before any tab connects: a tab resets its view when the opening camera first arrives
            try:
                self.frame_new_tabs(load_timeline(self.folder / names[0]))
            except (ValueError, OSError):
                pass  # the tab will say why; it frames whatever it opens
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)
        self._stop = threading.Event()
        self._ticker = threading.Thread(target=self._tick_loop, daemon=True)
        self._ticker.start()

    @property
    def port(self) -> int:
        return self.server.get_port()

    def replay_names(self) -> list[str]:
        return sorted(p.relative_to(self.folder).as_posix() for p in self.folder.rglob("*.replay.json"))

    def frame_new_tabs(self, data: dict) -> None:
        """Aim the camera that new tabs open with (and "reset view" returns to) at this replay's board."""
        size = (data["width"], data["height"])
        if size != self.new_tab_board:
            self.new_tab_board = size
            aim(self.server.initial_camera, framing_camera(*board_bounds(data)))

    def _connect(self, client) -> None:
        view = TabView(self, client)
        with self.lock:
            self.views[client.client_id] = view

    def _disconnect(self, client) -> None:
        with self.lock:
            self.views.pop(client.client_id, None)

    def _tick_loop(self) -> None:
        while not self._stop.wait(0.02):
            with self.lock:
                views = list(self.views.values())
            now = time.monotonic()
            for view in views:
                try:
                    view.tick(now)
                except Exception:  # a tab that went away mid-update
                    pass

    def stop(self) -> None:
        self._stop.set()
        self.server.stop()


_QUIET = threading.Lock()


@contextmanager
def quiet_viser():
    """Silence viser's console (its address banner, "Server stopped"): it prints through rich's
    global console whatever ``verbose`` says. One quiet stretch at a time, so each restores what it found."""
    console = rich.get_console()
    with _QUIET:
        was = console.quiet
        console.quiet = True
        try:
            yield
        finally:
            console.quiet = was


STEP_COUNTER = """<style>.mantine-NumberInput-root { visibility: hidden; }
#colorgrid-step { position: fixed; z-index: 10; display: flex; align-items: center; justify-content: center;
  font: 12px ui-monospace, monospace; pointer-events: none; }</style>
<script>
// The export's step counter, over viser's playback clock (which reads seconds to a tenth, one step being
// STEP_SECONDS of them): the whole step the scene shows, read from the playback slider.
(() => {
  const stepSeconds = __STEP_SECONDS__, steps = __STEPS__;
  const counter = document.createElement("span");
  counter.id = "colorgrid-step";
  setInterval(() => {
    const clock = document.querySelector(".mantine-NumberInput-root");
    const slider = document.querySelector("[role=slider][aria-valuenow]");
    if (!clock || !slider) return;
    if (!counter.isConnected) document.body.append(counter);
    const box = clock.getBoundingClientRect();
    Object.assign(counter.style, { left: `${box.left}px`, top: `${box.top}px`, width: `${box.width}px`,
                                   height: `${box.height}px` });
    const step = Math.min(steps, Math.floor(Number(slider.getAttribute("aria-valuenow")) / stepSeconds + 1e-6));
    counter.textContent = String(step);
    counter.title = `step ${step} of ${steps}`;
  }, 50);
})();
</script>"""
"""Put into the standalone page: a counter of whole steps where viser's clock was (its slider runs on)."""


def standalone_html(data: dict, name: str) -> str:
    """A standalone, offline HTML page playing the replay in 3D, one recording second per step.

    The scene is recorded through a private, silent viser server on a free local port: the board,
    the panel and charts drawn into the scene (``ScenePanel``), and a camera framing both.
    """
    with quiet_viser():
        server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
        try:
            grid = GridScene(server.scene, data)
            panel = ScenePanel(server.scene, data, title=name)
            aim(server.initial_camera, framing_camera(*panel.bounds(), aspect=EXPORT_ASPECT))
            recorder = server.get_scene_serializer()
            for t in range(data["steps"] + 1):
                grid.show(t)
                panel.show(t)
                recorder.insert_sleep(STEP_SECONDS)
            page = recorder.as_html()
        finally:
            server.stop()
    counter = STEP_COUNTER.replace("__STEP_SECONDS__", repr(STEP_SECONDS)).replace("__STEPS__", str(data["steps"]))
    page = page.replace("</body>", f"{counter}\n</body>", 1)
    return page.replace("<title>Viser</title>", f"<title>ColorGrid replay: {html.escape(name)}</title>", 1)


def export_html(replay_path: str | Path, out_path: str | Path) -> Path:
    """Write ``standalone_html`` of a replay file to ``out_path`` (atomically); return the path."""
    from colorgrid.files import atomic_path

    data = load_timeline(Path(replay_path))
    page = standalone_html(data, Path(replay_path).name)
    out = Path(out_path)
    with atomic_path(out) as tmp:
        tmp.write_text(page)
    return out
