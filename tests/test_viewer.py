"""The 3D replay viewer (viser): scene and chart state without a browser, then a real browser connects."""

import base64
import glob
import re
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zstandard
from playwright.sync_api import expect

from colorgrid.replay import load, save
from colorgrid.replay.timeline import timeline
from colorgrid_apps.viewer import ReplayViewer, TabView
from colorgrid_apps.viewer_export import export_html
from colorgrid_apps.viewer_frames import STEP_SECONDS, block_capacity, board_bounds, frame_at, framing_camera
from tests.helpers import wait_until

ROOT = Path(__file__).resolve().parents[1]
BAYES = sorted(glob.glob(str(ROOT / "replays/default/astar+bayes*.replay.json")))[0]


def in_view(points, position, look_at, up, fov, aspect) -> np.ndarray:
    """Where ``points`` land on a pinhole camera's image, in [-1, 1] when inside its frustum: ``[N, 2]``."""
    forward = np.asarray(look_at, float) - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    image_up = np.cross(right, forward)
    rel = np.asarray(points, float) - position
    depth = rel @ forward
    assert (depth > 0).all(), "a point behind the camera"
    half = np.tan(fov / 2)
    return np.stack([rel @ right / (depth * half * aspect), rel @ image_up / (depth * half)], axis=1)


def board_corners(data) -> np.ndarray:
    """The four corners of the board (its goal-colored rim), on the floor."""
    W, H = data["width"], data["height"]
    return np.array([[-0.5, -0.5, 0.0], [W + 0.5, -0.5, 0.0], [-0.5, H + 0.5, 0.0], [W + 0.5, H + 0.5, 0.0]])


def read_recording(page: str) -> tuple[dict, list[bytes]]:
    """The viser recording embedded in a standalone page: its messages and binary buffers (viser's
    ``StateSerializer.serialize`` layout: zstd of [msgpack length][msgpack][8-byte aligned buffers])."""
    payload = base64.b64decode(re.search(r'__VISER_EMBED_DATA__="([^"]+)"', page).group(1))
    inner = zstandard.ZstdDecompressor().decompress(payload[8:], max_output_size=int.from_bytes(payload[:8], "little"))
    n = int.from_bytes(inner[:8], "little")
    recording = msgspec.msgpack.decode(inner[8:8 + n])
    buffers, offset = [], 8 + n
    for length in recording["binaryBufferLengths"]:
        offset += -offset % 8
        buffers.append(inner[offset:offset + length])
        offset += length
    return recording, buffers


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
    assert [s["label"] for s in tab.chart.series] == ["step", "red", "green", "blue"], "the cursor is no series"
    assert tab.chart.scales["x"]["time"] is False  # uPlot reads x as unix time otherwise: "1/1/70 12:00am"
    x, *curves = tab.chart.data
    assert np.array_equal(x, np.arange(129)) and len(curves) == 3
    cursor = tab.chart.axes[2]  # an axis on x whose one grid line is the cursor
    assert cursor["scale"] == "x" and cursor["splits"] == (128.0,) and cursor["values"] == ("step 128",)
    assert cursor["grid"]["show"] is True  # the cursor follows the slider
    probs = np.asarray(data["goal_probs"]["follower"])
    for k, curve in enumerate(curves):
        assert np.allclose(curve[:128], probs[:, k]) and np.isnan(curve[128])  # no belief after the last action


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


def test_the_opening_camera_frames_the_whole_board(viewer):
    tab = TabView(viewer, viewer.server)  # what every new tab opens with (and "reset view" returns to)
    camera = viewer.server.initial_camera
    spots = in_view(board_corners(tab.data), camera.position, camera.look_at, camera.up, camera.fov, aspect=1.0)
    assert (np.abs(spots) <= 1).all(), spots  # a square canvas sees all four corners; wider ones see more
    assert np.abs(spots).max() > 0.7, "the board fills the view, not a speck in it"
    tall = framing_camera(*board_bounds(tab.data), aspect=0.6)
    spots = in_view(board_corners(tab.data), tall.position, tall.look_at, tall.up, tall.fov, aspect=0.6)
    assert (np.abs(spots) <= 1).all(), spots  # a tab reporting a narrow canvas is framed for it


def test_standalone_html_export_carries_the_panel_and_chart_and_counts_steps(tmp_path, browser):
    out = export_html(BAYES, tmp_path / "replay.html")
    html = out.read_text()
    assert not re.search(r"""(src|href)=["']https?://""", html), "the export must not load anything from the web"
    recording, buffers = read_recording(html)
    data = timeline(load(BAYES))
    assert recording["durationSeconds"] == (data["steps"] + 1) * STEP_SECONDS == 129  # slider and clock read steps
    messages = recording["messages"]
    facts = {}  # recording time -> the panel's text then
    for at, message in messages:
        if message.get("name") == "/panel/facts" and "text" in message.get("updates", {}):
            facts[at] = message["updates"]["text"]
    for t in (0, 40, 128):
        board = data["boards"][t]
        assert f"step {t} / 128" in facts[t * STEP_SECONDS]
        assert f"goal: {data['colors'][board['goal']]}" in facts[t * STEP_SECONDS]
        assert f"team {sum(board['scores']):+.0f}" in facts[t * STEP_SECONDS]
    labels = {m["props"]["text"] for _, m in messages if m["type"] == "LabelMessage"}
    assert {"follower's goal probabilities", "red", "green", "blue", "step", "0", "128"} <= labels
    probs = np.asarray(data["goal_probs"]["follower"])
    curves = {m["name"]: m["props"]["points"] for _, m in messages if m["type"] == "LineSegmentsMessage"}
    for k, name in enumerate(data["colors"]):
        placeholder = curves[f"/panel/chart/{name}"]
        segments = np.frombuffer(buffers[placeholder["__binary_index"]], dtype=placeholder["dtype"]).reshape(-1, 2, 3)
        heights = np.append(segments[:, 0, 1], segments[-1, 1, 1]) / (data["height"] / 2)
        assert np.allclose(heights, probs[:, k], atol=1e-5)
    cursor = {}  # recording time -> the chart cursor's x then
    for at, message in messages:
        if message.get("name") == "/panel/chart/now" and "position" in message:
            cursor[at] = message["position"][0]
    left, right = cursor[0.0], cursor[128 * STEP_SECONDS]
    assert (cursor[40 * STEP_SECONDS] - left) / (right - left) == pytest.approx(40 / 128)

    page = browser.new_page()
    requests = []
    page.on("request", lambda r: requests.append(r.url))
    page.goto(out.as_uri())
    page.wait_for_selector("canvas", timeout=30000)
    counter = page.locator("#colorgrid-step")
    counter.wait_for(timeout=30000)  # whole steps where viser's clock shows tenths of a second
    expect(page.locator(".mantine-NumberInput-root")).to_be_hidden()
    slider = page.locator(".mantine-Slider-root")
    area = slider.bounding_box()
    seen = set()
    read = """() => [document.getElementById("colorgrid-step").textContent,
                     Number(document.querySelector("[role=slider]").getAttribute("aria-valuenow"))]"""
    for fraction in (0.3, 0.62):  # seeking pauses playback at a time between two steps
        before = page.evaluate(read)[1]
        slider.click(position={"x": area["width"] * fraction, "y": area["height"] / 2})
        # the clock has moved to where the slider was clicked, and the counter shows that time's whole step
        shown, clock = page.wait_for_function(f"""() => {{
            const [shown, clock] = ({read})();
            return clock !== {before} && shown === String(Math.floor(clock / {STEP_SECONDS})) && [shown, clock];
        }}""").json_value()
        assert abs(clock / recording["durationSeconds"] - fraction) < 0.1, (clock, fraction)
        seen.add(shown)
    assert len(seen) == 2
    box, clock_box = counter.bounding_box(), page.locator(".mantine-NumberInput-root").bounding_box()
    assert box == clock_box, "in the clock's place"
    assert all(u.startswith(("file:", "data:", "blob:")) for u in requests), requests
    page.close()


def test_export_command_prints_only_what_it_wrote(tmp_path):
    out = tmp_path / "replay.html"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "view", BAYES, "--export", str(out)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout == f"wrote {out}\n"  # no address of the private server it recorded through
    assert "__VISER_EMBED_DATA__" in out.read_text()


def test_the_export_button_sends_the_file_to_the_browser_and_writes_nothing(viewer, browser, tmp_path):
    before = sorted(viewer.folder.rglob("*"))
    page = browser.new_page(accept_downloads=True)
    try:
        page.goto(f"http://127.0.0.1:{viewer.port}/")
        button = page.get_by_text("export standalone HTML")
        with page.expect_download(timeout=120_000) as info:  # the page is recorded on the server first
            button.click()
        download = info.value
        assert download.suggested_filename == "a.html"
        download.save_as(tmp_path / "a.html")
        content = (tmp_path / "a.html").read_bytes()
        assert b"__VISER_EMBED_DATA__" in content and b"<title>ColorGrid replay: a.replay.json</title>" in content
        expect(page.get_by_text("to the browser")).to_have_text("sent a.html to the browser")
    finally:
        page.close()
    assert sorted(viewer.folder.rglob("*")) == before


def test_a_browser_tab_opens_on_the_whole_board_with_a_step_chart(viewer, browser):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    try:
        page.goto(f"http://127.0.0.1:{viewer.port}/")
        page.get_by_text("play / pause").wait_for(timeout=30000)
        data = timeline(load(BAYES))
        center = np.array([data["width"] / 2, data["height"] / 2, 0.4])
        scene_aspect = """() => {  // the 3D canvas (the largest: the chart draws on one too), as laid out now
            const c = [...document.querySelectorAll("canvas")].sort((a, b) =>
                b.clientWidth * b.clientHeight - a.clientWidth * a.clientHeight)[0];
            return c.clientWidth / c.clientHeight;
        }"""

        def camera_reported():
            """The tab's camera once the browser reports it aimed at the board, for its canvas as docked beside
            the panel."""
            clients = list(viewer.server.get_clients().values())
            if not clients or not np.allclose(clients[0].camera.look_at, center, atol=1e-3):
                return None
            camera = clients[0].camera
            try:
                return camera if abs(camera.aspect - page.evaluate(scene_aspect)) < 1e-3 else None
            except AssertionError:  # viser: no size reported by the browser yet
                return None

        camera = wait_until(camera_reported, "the tab's camera aimed at the board, for the canvas beside the panel")
        clients = list(viewer.server.get_clients().values())
        spots = in_view(board_corners(data), camera.position, camera.look_at, camera.up_direction, camera.fov,
                        camera.aspect)
        assert (np.abs(spots) <= 1).all(), (spots, camera.aspect)
        view = viewer.views[clients[0].client_id]
        view.slider.value = 60
        chart = "Object.values(window.__viserTestpoints.uplots)[0].chart"
        cursor = f"{chart}.axes[2]"
        page.wait_for_function(f"() => {cursor}.splits({chart}, 2, 0, 128)[0] === 60", timeout=30000)  # it moved
        assert page.evaluate(f"() => {chart}.series.map(s => s.label)") == ["step", "red", "green", "blue"]
        legend = page.locator(".u-legend .u-series").all_inner_texts()
        assert not any("now" in row or "step 60" in row for row in legend), legend  # the legend lists curves only
        # drawn (on a frame after the move): a dark vertical line across the plot at step 60, whatever the curves
        line = page.wait_for_function(f"""() => {{
            const u = {chart}, x = Math.round(u.valToPos(60, "x", true)), top = u.bbox.top, height = u.bbox.height;
            const ctx = u.ctx;
            const line = [0.1, 0.3, 0.5, 0.7, 0.9].map(f =>
                [...ctx.getImageData(x, Math.round(top + f * height), 1, 1).data]);
            return line.every(rgba => Math.max(...rgba.slice(0, 3)) < 80 && rgba[3] > 200) && line;
        }}""").json_value()
        assert all(max(rgba[:3]) < 80 and rgba[3] > 200 for rgba in line), line
        ticks = f"{chart}.axes[0].values({chart}, [0, 64, 128], 0, 50, 64)"  # the x axis's label formatter
        time_scale, ticks = page.evaluate(f"() => [{chart}.scales.x.time, {ticks}]")
        assert time_scale is False and ticks == ["0", "64", "128"], ticks  # x labels are steps, not "1/1/70 12:00am"
    finally:
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
