"""The 3D replay viewer's export: a replay recorded into one standalone, offline HTML page (``standalone_html``),
which plays one recording second per step under a counter of whole steps (``viewer_step_counter.js``)."""

from __future__ import annotations

import html
import threading
from contextlib import contextmanager
from importlib.resources import files
from pathlib import Path

import rich
import viser

from colorgrid_apps.viewer_frames import EXPORT_ASPECT, STEP_SECONDS, aim, framing_camera, load_timeline
from colorgrid_apps.viewer_scene import GridScene, ScenePanel

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



STEP_COUNTER_STYLE = """<style>.mantine-NumberInput-root { visibility: hidden; }
#colorgrid-step { position: fixed; z-index: 10; display: flex; align-items: center; justify-content: center;
  font: 12px ui-monospace, monospace; pointer-events: none; }</style>"""


def step_counter(steps: int) -> str:
    """Put into the standalone page: a counter of whole steps where viser's clock was (its slider runs on); its
    script is the shipped ``viewer_step_counter.js``."""
    script = files("colorgrid_apps").joinpath("viewer_step_counter.js").read_text(encoding="utf-8")
    script = script.replace("__STEP_SECONDS__", repr(STEP_SECONDS)).replace("__STEPS__", str(steps))
    return f"{STEP_COUNTER_STYLE}\n<script>\n{script}</script>"


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
    page = page.replace("</body>", f"{step_counter(data['steps'])}\n</body>", 1)
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
