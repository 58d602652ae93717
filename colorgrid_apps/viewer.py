"""The 3D replay viewer (``colorgrid view [PATH]``): every viser call of the project lives in this module.

A viser server on 127.0.0.1 shows a replay's grid as batched meshes (floor, one batch of
cubes per block color, the two agents with labels), with a per-tab panel: a dropdown of the
replays in a folder, a step slider, play/pause and speed, step/scores/goal, and a uPlot chart
of the follower's goal probabilities. Each tab gets its own scene and controls, so tabs scrub
independently. ``export_html`` writes a standalone offline HTML file (the viser client with
the recorded scene embedded). viser is pinned in ``pyproject.toml``: client and server must match.
"""

from __future__ import annotations

import base64
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import viser
import viser.uplot

from colorgrid.config import AGENTS, FOLLOWER, SYMBOLS
from colorgrid.render import AGENT_COLORS, FLOOR, PALETTE
from colorgrid.replay import ReplayError, load
from colorgrid.replay.timeline import timeline

SPEEDS = ("0.25", "0.5", "1", "2", "4", "8")
BASE_FPS = 8.0
HIDDEN_Z = -50.0  # where unused block instances wait
BELIEVER = AGENTS[FOLLOWER]  # whose goal probabilities the panel shows


def unit_cube() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], dtype=np.float32)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.uint32)
    return v, f


@dataclass
class Frame:
    """The scene at one step, as arrays: what the meshes are set to (pure data, easy to test)."""

    block_positions: list  # per color: [N_k, 3] float32 (unused instances below the floor)
    agents: np.ndarray  # [A, 3] float32, in index order (``AGENTS``)
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
    agents = np.stack([cell_xyz(board[name], W, H, 0.45) for name in AGENTS])
    return Frame(positions, agents, board["goal"])


def block_capacity(data: dict) -> list[int]:
    """Instances per color: the most blocks of that color on any step."""
    counts = np.zeros(len(data["colors"]), dtype=np.int64)
    for board in data["boards"]:
        codes = np.frombuffer(board["blocks"].encode(), dtype=np.uint8).astype(np.int64) - ord("0")
        counts = np.maximum(counts, np.bincount(codes[codes >= 0], minlength=len(counts)))
    return counts.tolist()


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
        for i, name in enumerate(AGENTS):
            body = np.minimum(AGENT_COLORS[i][0], 235)  # pure white glares under the scene's light
            self.agents[name] = scene.add_icosphere(f"{root}/{name}", radius=0.45, position=first.agents[i],
                                                    color=tuple(int(x) for x in body))
            scene.add_label(f"{root}/{name}/label", f"{SYMBOLS[i]} ({name})", position=(0.0, 0.0, 0.8))
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


def belief_series(data: dict) -> tuple[tuple[np.ndarray, ...], tuple]:
    """uPlot data (steps, then one probability curve per color) of the follower's beliefs; None if it has none."""
    probs = data.get("goal_probs", {}).get(BELIEVER)
    if not probs:
        return None, ()
    arr = np.asarray(probs, dtype=np.float64)
    x = np.arange(arr.shape[0], dtype=np.float64)
    series = (viser.uplot.Series(label="step"),
              *(viser.uplot.Series(label=name, stroke=data["look"]["palette"][k], width=2)
                for k, name in enumerate(data["colors"])))
    return (x, *(arr[:, k] for k in range(arr.shape[1]))), series


class TabView:
    """One browser tab: its own scene, controls, playback state."""

    def __init__(self, viewer: "ReplayViewer", target, root: str = "/grid"):
        self.viewer, self.target, self.root = viewer, target, root
        gui = target.gui
        self.grid: GridScene | None = None
        self.data: dict | None = None
        self.chart = None
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
        if self.chart is not None:
            self.chart.remove()
            self.chart = None
        self.data, self.name = data, name
        self.grid = GridScene(self.target.scene, data, self.root)
        self.slider.max = data["steps"]
        series_data, series = belief_series(data)
        if series_data is not None:
            self.chart = self.target.gui.add_uplot(series_data, series, title=f"{BELIEVER}'s goal probabilities",
                                                   scales={"y": viser.uplot.Scale(range=(0.0, 1.0))}, aspect=2.0)
        self.slider.value = 0
        self.show(0)

    def show(self, t: int) -> None:
        if self.data is None:
            return
        t = max(0, min(self.data["steps"], t))
        frame = self.grid.show(t)
        board = self.data["boards"][t]
        goal = self.data["colors"][frame.goal]
        scores = board["scores"]
        lines = [f"**{self.name}**", f"step **{t}** / {self.data['steps']}", f"goal: **{goal}**"]
        if scores is not None:
            each = ", ".join(f"{name} {score:+.0f}" for name, score in zip(AGENTS, scores))
            lines.append(f"team **{sum(scores):+.0f}** ({each})")
        probs = self.data.get("goal_probs", {}).get(BELIEVER)
        if probs:
            row = probs[min(t, len(probs) - 1)]
            lines.append(f"{BELIEVER} believes: " + ", ".join(f"{c} {p:.2f}" for c, p in zip(self.data["colors"], row)))
        self.info.content = "  \n".join(lines)
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
        if self.data is None:
            return
        out = self.viewer.folder / "exports" / (Path(self.name).name.removesuffix(".replay.json") + ".html")
        path = export_html(self.viewer.folder / self.name, out)
        self.export_note.content = f"wrote `{path}`"
        if hasattr(self.target, "send_file_download"):
            self.target.send_file_download(path.name, path.read_bytes())


class ReplayViewer:
    """The viser server; one ``TabView`` per connected tab, and a thread that advances playing tabs."""

    def __init__(self, folder: str | Path, host: str = "127.0.0.1", port: int = 8080):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FileNotFoundError(f"{self.folder} is not a folder of replays")
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.gui.configure_theme(show_share_button=False, control_width="large")
        self.views: dict[int, TabView] = {}
        self.lock = threading.Lock()
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


def export_html(replay_path: str | Path, out_path: str | Path, fps: float = BASE_FPS) -> Path:
    """A standalone, offline HTML file playing the replay in 3D (the viser client with the scene embedded)."""
    from colorgrid.files import atomic_path

    data = load_timeline(Path(replay_path))
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        recorder = server.get_scene_serializer()
        grid = GridScene(server.scene, data)
        for t in range(data["steps"] + 1):
            grid.show(t)
            recorder.insert_sleep(1.0 / fps)
        payload = base64.b64encode(recorder.serialize()).decode("ascii")
    finally:
        server.stop()
    client = (Path(viser.__file__).parent / "client" / "build" / "index.html").read_text()
    head = (f"<head><title>ColorGrid replay: {Path(replay_path).name}</title>"
            f"<script>window.__VISER_EMBED_DATA__ = \"{payload}\";</script>")
    html = client.replace("<head>", head, 1)
    out = Path(out_path)
    with atomic_path(out) as tmp:
        tmp.write_text(html)
    return out
