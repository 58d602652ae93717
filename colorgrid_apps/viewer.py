"""The 3D replay viewer (``colorgrid view [PATH]``), its app: the viser server and a tab's controls. Every viser
call of the project lives in this module and its siblings, one job each: ``viewer_frames`` (frames and camera),
``viewer_scene`` (scene and panel), ``viewer_export`` (the standalone page).

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

import threading
import time
from pathlib import Path

import viser

from colorgrid_apps.viewer_export import standalone_html
from colorgrid_apps.viewer_frames import aim, board_bounds, canvas_aspect, framing_camera, load_timeline
from colorgrid_apps.viewer_scene import (GridScene, belief_axes, belief_scales, belief_series, believers, chart_title,
                                         step_summary)

SPEEDS = ("0.25", "0.5", "1", "2", "4", "8")
BASE_FPS = 8.0


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

