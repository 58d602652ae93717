"""The 3D replay viewer (viser): scene and chart state without a browser, then a real browser connects."""

import glob
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from colorgrid.replay import load, save
from colorgrid.replay.timeline import timeline
from colorgrid_apps.viewer import ReplayViewer, TabView, block_capacity, export_html, frame_at

ROOT = Path(__file__).resolve().parents[1]
BAYES = sorted(glob.glob(str(ROOT / "replays/default/astar+bayes*.replay.json")))[0]


@pytest.fixture()
def viewer(tmp_path):
    folder = tmp_path / "replays"
    folder.mkdir()
    replay = load(BAYES)
    save(replay, folder / "a.replay.json")
    replay.actions[3] = [(replay.actions[3][0] + 1) % 4, replay.actions[3][1]]
    save(replay, folder / "b_tampered.replay.json")
    v = ReplayViewer(folder, port=0)
    yield v
    v.stop()


def test_scene_follows_the_slider_and_the_chart_holds_the_beliefs(viewer):
    assert viewer.port > 0
    tab = TabView(viewer, viewer.server)  # the server-wide scene stands in for one tab
    data = timeline(load(BAYES))
    assert tab.dropdown.options == ("a.replay.json", "b_tampered.replay.json")
    assert tab.slider.max == data["steps"] == 128
    for t in (0, 40, 128):
        tab.slider.value = t
        board = data["boards"][t]
        r, c = divmod(board["leader"], data["width"])
        assert np.allclose(tab.grid.agents["leader"].position, (c + 0.5, data["height"] - r - 0.5, 0.45))
        r, c = divmod(board["follower"], data["width"])
        assert np.allclose(tab.grid.agents["follower"].position, (c + 0.5, data["height"] - r - 0.5, 0.45))
        for k, handle in enumerate(tab.grid.blocks):  # every block of color k sits on a cell of color k
            visible = handle.batched_positions[handle.batched_positions[:, 2] > 0]
            cells = [(data["height"] - 1 - int(y)) * data["width"] + int(x) for x, y, _ in visible]
            assert sorted(cells) == [i for i, ch in enumerate(board["blocks"]) if ch == str(k)]
        assert f"step **{t}** / 128" in tab.info.content
    assert tab.chart is not None
    x, *curves = tab.chart.data
    assert len(x) == 128 and len(curves) == 3
    probs = np.asarray(data["goal_probs"]["follower"])
    for k, curve in enumerate(curves):
        assert np.allclose(curve, probs[:, k])


def test_a_tampered_replay_is_refused_with_its_reason(viewer):
    tab = TabView(viewer, viewer.server)
    tab.dropdown.value = "b_tampered.replay.json"
    assert "failed verification" in tab.info.content and "state hash mismatch" in tab.info.content
    assert tab.name == "a.replay.json"  # the last good replay stays on screen


def test_tabs_scrub_independently(viewer):
    one, two = TabView(viewer, viewer.server, root="/one"), TabView(viewer, viewer.server, root="/two")
    one.slider.value = 10
    two.slider.value = 90
    assert (one.step, two.step) == (10, 90)
    assert not np.allclose(one.grid.agents["leader"].position, two.grid.agents["leader"].position)


def test_playback_advances_at_the_chosen_speed(viewer):
    tab = TabView(viewer, viewer.server)
    tab.speed.value = "8"
    tab.toggle()
    now = time.monotonic()
    for i in range(5):
        tab.tick(now + i)  # one tick per call: the clock moved past the next frame time
    assert tab.step == 5
    tab.toggle()
    tab.tick(now + 100)
    assert tab.step == 5


def test_frames_place_every_block_once(viewer):
    data = timeline(load(BAYES))
    cap = block_capacity(data)
    assert cap == [34, 34, 34]
    frame = frame_at(data, 7, cap)
    assert sum(int((p[:, 2] > 0).sum()) for p in frame.block_positions) == 102


def test_standalone_html_export_plays_offline(tmp_path, browser):
    out = export_html(BAYES, tmp_path / "replay.html")
    html = out.read_text()
    assert "__VISER_EMBED_DATA__" in html
    assert not re.search(r"""(src|href)=["']https?://""", html), "the export must not load anything from the web"
    page = browser.new_page()
    requests = []
    page.on("request", lambda r: requests.append(r.url))
    page.goto(out.as_uri())
    page.wait_for_selector("canvas", timeout=30000)
    page.wait_for_timeout(500)
    assert all(u.startswith(("file:", "data:", "blob:")) for u in requests), requests
    page.close()


def test_view_command_serves_a_page_a_browser_connects_to(tmp_path, browser):
    proc = subprocess.Popen([sys.executable, "-m", "colorgrid_apps", "view", str(ROOT / "replays"), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT)
    try:
        url = None
        deadline = time.monotonic() + 60
        while url is None and time.monotonic() < deadline:
            line = proc.stdout.readline()
            match = re.search(r"ColorGrid 3D viewer: (http://127\.0\.0\.1:\d+/)", line)
            url = match.group(1) if match else None
        assert url, "the viewer printed its address"
        page = browser.new_page()
        page.goto(url)
        page.wait_for_selector("canvas", timeout=30000)
        page.get_by_text("play / pause").wait_for(timeout=30000)  # the tab's own panel arrived over the websocket
        assert page.get_by_text("share", exact=True).count() == 0
        page.close()
    finally:
        proc.terminate()
        proc.wait(timeout=20)
