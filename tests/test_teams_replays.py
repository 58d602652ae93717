"""Replays of teams of any shape (``num_leaders`` x ``num_followers``): the file, the CLI, the GIF export, the
timeline, the 3D viewer and the web replay player draw and list every agent; 1:1 files from before teams stay as
they were.

The team replays are made here from real ``BatchEnv`` steps (seeded random moves), with simple beliefs: a
follower's goal probabilities are proportional to one plus the leaders' pickups of each color so far.
"""

import json
import subprocess
import sys
from urllib.parse import quote

import imageio.v2 as imageio
import numpy as np
import pytest
from PIL import Image, ImageDraw
from playwright.sync_api import expect

from colorgrid import BatchEnv, EnvConfig
from colorgrid.config import TEAM_ENV_ID
from colorgrid.render import AGENT_COLORS, _font, tiles
from colorgrid.replay import Replay, load, save, verify
from colorgrid.replay.timeline import timeline
from colorgrid.replay.export import PANEL_BG, PANEL_WIDTH, episode_frames, export, panel_height
from colorgrid_apps.viewer import ReplayViewer, TabView
from colorgrid_apps.viewer_export import standalone_html
from tests.conftest import ROOT
from tests.test_viewer import read_recording

OLD_FILE = ROOT / "replays" / "default" / "astar+bayes_seed2026.replay.json"  # released before teams existed
CELL = 24  # pixels per cell in the exports


def team_replay(num_leaders: int, num_followers: int, believers: tuple[str, ...] | None = None, seed: int = 7,
                horizon: int = 30) -> Replay:
    """An actions replay of one episode on a 10x10 grid, stepped through ``BatchEnv`` with seeded random moves.

    ``believers``: the agents that log goal probabilities (default: every follower).
    """
    config = EnvConfig(num_leaders=num_leaders, num_followers=num_followers, height=10, width=10, horizon=horizon,
                       block_density=0.2)
    env = BatchEnv(config, num_envs=1, seed=seed, autoreset=False)
    env.reset()
    rng = np.random.default_rng(seed)
    believers = config.agent_names[num_leaders:] if believers is None else believers
    leader_pickups = np.ones(config.num_colors)
    steps = {k: [] for k in ("actions", "goal", "block_reward", "team_reward", "picked_color", "goal_switched")}
    probs = {name: [] for name in believers}
    hashes = [env.state.state_hash(0)]
    for _ in range(horizon):
        for name in believers:
            probs[name].append((leader_pickups / leader_pickups.sum()).round(5).tolist())
        actions = rng.integers(0, config.num_actions, (1, config.num_agents))
        steps["goal"].append(int(env.state.goal[0]))
        *_, info = env.step(actions)
        for color in info["picked_color"][0, list(config.leaders)]:
            if color >= 0:
                leader_pickups[color] += 1
        steps["actions"].append(actions[0].tolist())
        steps["block_reward"].append(info["block_reward"][0].tolist())
        steps["team_reward"].append(float(info["team_reward"][0]))
        steps["picked_color"].append(info["picked_color"][0].tolist())
        steps["goal_switched"].append(bool(info["goal_switched"][0]))
        hashes.append(env.state.state_hash(0))
    return Replay(config=config, seed=int(env.state.seed[0]), source="eval",
                  agents={name: {"policy": "random"} for name in config.agent_names}, goal_probs=probs,
                  state_hashes=hashes, **steps)


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "colorgrid_apps", *args], capture_output=True, text=True, cwd=ROOT,
                          timeout=300)


# ------------------------------------------------------------ the file and the CLI
def test_a_2_by_2_replay_saves_loads_and_verifies(tmp_path):
    replay = team_replay(2, 2)
    path = save(replay, tmp_path / "team.replay.json")
    doc = json.loads(path.read_text())
    assert doc["env_id"] == TEAM_ENV_ID == "colorgrid_teams_v0"
    assert doc["agent_names"] == ["leader_0", "leader_1", "follower_0", "follower_1"]
    assert doc["roles"] == ["leader", "leader", "follower", "follower"]
    assert sorted(doc["steps"]["goal_probs"]) == ["follower_0", "follower_1"]
    loaded = load(path)
    assert loaded.config == replay.config and loaded.actions == replay.actions
    assert loaded.goal_probs == replay.goal_probs and loaded.final() == replay.final()
    assert verify(loaded).ok
    assert sum(p >= 0 for row in loaded.picked_color for p in row) > 0, "the episode has pickups to draw"

    done = run_cli("replay", "verify", str(path))
    assert done.returncode == 0, done.stderr
    final = replay.final()
    expected = [f"{path}: ok"] + [
        f"  {symbol} {name} ({role}, random): {final[f'{name}_score']:+g} ({final[f'{name}_goal_pickups']} goal, "
        f"{final[f'{name}_wrong_pickups']} wrong){', beliefs' if role == 'follower' else ''}"
        for symbol, name, role in zip(("L1", "L2", "F1", "F2"), doc["agent_names"], doc["roles"])]
    assert done.stdout.splitlines() == expected

    done = run_cli("replay", "info", str(path))
    assert done.returncode == 0, done.stderr
    info = json.loads(done.stdout)
    assert info["env_id"] == "colorgrid_teams_v0"
    assert [(a["symbol"], a["name"], a["role"], a["beliefs"]) for a in info["team"]] == [
        ("L1", "leader_0", "leader", False), ("L2", "leader_1", "leader", False),
        ("F1", "follower_0", "follower", True), ("F2", "follower_1", "follower", True)]
    assert [a["score"] for a in info["team"]] == [final[f"{name}_score"] for name in doc["agent_names"]]

    tampered = load(path)  # a changed move of the last follower is caught at the step after it
    for t, action in enumerate(tampered.actions):
        tampered.actions[t] = action[:3] + [(action[3] + 1) % 4]
        if not verify(tampered).ok:
            assert verify(tampered).first_bad_step == t + 1
            break
        tampered.actions[t] = action
    else:
        pytest.fail("no changed move of follower_1 changed the episode")
    save(tampered, tmp_path / "tampered.replay.json")
    done = run_cli("replay", "verify", str(tmp_path / "tampered.replay.json"))
    assert done.returncode == 1 and "state hash mismatch" in done.stdout.splitlines()[0]
    assert len(done.stdout.splitlines()) == 5, "the team's agents are listed under a failing file too"


def test_a_file_written_before_teams_still_loads_and_verifies_unchanged(tmp_path):
    doc = json.loads(OLD_FILE.read_text())
    assert "agent_names" not in doc and "roles" not in doc and doc["env_id"] == "colorgrid_v0"
    replay = load(OLD_FILE)
    assert replay.config.one_to_one and replay.config.agent_names == ("leader", "follower")
    assert verify(replay).ok
    data = timeline(replay)
    assert data["verified"] and data["agent_names"] == ["leader", "follower"]
    assert [a["symbol"] for a in data["look"]["agents"]] == ["L", "F"]
    assert list(data["goal_probs"]) == ["follower"]
    done = run_cli("replay", "verify", str(OLD_FILE))
    assert done.returncode == 0 and done.stdout == f"{OLD_FILE}: ok\n"  # one line, as before teams
    done = run_cli("replay", "info", str(OLD_FILE))
    info = json.loads(done.stdout)
    assert [(a["symbol"], a["name"], a["policy"]) for a in info["team"]] == [("L", "leader", "astar"),
                                                                            ("F", "follower", "bayes")]
    again = load(save(replay, tmp_path / "again.replay.json"))  # written now, it lists its agents
    assert json.loads((tmp_path / "again.replay.json").read_text())["agent_names"] == ["leader", "follower"]
    assert again.state_hashes == replay.state_hashes and verify(again).ok


# ------------------------------------------------------------ the timeline
def test_the_timeline_lists_every_agent_with_a_cell_per_step():
    replay = team_replay(2, 2)
    data = timeline(replay)
    assert data["verified"], data["problem"]
    assert data["agent_names"] == ["leader_0", "leader_1", "follower_0", "follower_1"]
    assert data["roles"] == ["leader", "leader", "follower", "follower"]
    assert [(a["name"], a["symbol"], a["body"]) for a in data["look"]["agents"]] == [
        ("leader_0", "L1", "#191919"), ("leader_1", "L2", "#191919"),
        ("follower_0", "F1", "#ffc800"), ("follower_1", "F2", "#ffc800")]
    assert len(data["boards"]) == replay.num_steps + 1
    for board in data["boards"]:
        cells = [board[name] for name in data["agent_names"]]
        assert len(set(cells)) == 4 and all(0 <= c < 100 for c in cells), "four agents on four cells"
        assert len(board["scores"]) == 4
    assert sum(data["boards"][-1]["scores"]) == pytest.approx(replay.final()["team_score"])
    assert sorted(data["goal_probs"]) == ["follower_0", "follower_1"]
    assert {e["agent"] for e in data["events"] if e["type"] == "pickup"} <= set(data["agent_names"])


# ------------------------------------------------------------ the GIF export
def bars(panel: np.ndarray) -> int:
    """Belief bars in a panel: each has a grey outline whose right edge is at x = 160 (its value ends before it)."""
    edge = (np.abs(panel[:, 160].astype(int) - 200).sum(axis=1) < 12).astype(int)  # (200, 200, 200)
    return int((np.diff(np.concatenate([[0], edge])) == 1).sum())


def text_at(panel: np.ndarray, text: str, x: int = 10) -> bool:
    """Whether ``text``, written at ``x`` in the panel's small font, appears in the panel at some height."""
    font = _font(11)
    left, top, right, bottom = ImageDraw.Draw(Image.new("RGB", (1, 1))).textbbox((x, 0), text, font=font)
    sample = Image.new("RGB", (PANEL_WIDTH, bottom + 2), PANEL_BG)
    ImageDraw.Draw(sample).text((x, 0), text, fill=(30, 30, 30), font=font)
    patch = np.asarray(sample)[top:bottom, left:right]
    return any(np.array_equal(panel[y + top:y + bottom, left:right], patch) for y in range(panel.shape[0] - bottom))


@pytest.mark.parametrize("shape, believers", [((2, 1), ("leader_1", "follower_0")), ((1, 2), ("follower_1",))])
def test_the_gif_of_a_team_draws_each_agent_with_its_label_and_one_chart_per_believer(tmp_path, shape, believers):
    replay = team_replay(*shape, believers=believers)
    cfg = replay.config
    out = export(replay, tmp_path / "team.gif", "gif", cell=CELL)
    frames = [np.asarray(f)[..., :3] for f in imageio.get_reader(out)]
    assert len(frames) == replay.num_steps + 1
    board_h, board_w = 22 + 10 * CELL + 8, 10 * CELL + 8
    height = max(board_h, panel_height(replay))
    assert height > board_h, "three agents' lines and their charts need more than this small board's height"
    assert frames[0].shape == (height + height % 2, board_w + PANEL_WIDTH, 3)
    agent_tiles = tiles(cfg, CELL)[1 + cfg.num_colors:].astype(int)  # one labelled tile per agent, index order
    assert len({t.tobytes() for t in agent_tiles}) == 3, "every agent's tile differs (its label)"
    states = timeline(replay)["boards"]
    for t in (0, 15, replay.num_steps):
        frame = frames[t].astype(int)
        for i, (name, role) in enumerate(zip(cfg.agent_names, cfg.roles)):
            r, c = divmod(states[t][name], cfg.width)
            drawn = frame[22 + 4 + r * CELL:22 + 4 + (r + 1) * CELL, 4 + c * CELL:4 + (c + 1) * CELL]
            mine = agent_tiles[i]  # the GIF palette moves colors a little, never by much
            assert np.abs(drawn - mine).max() <= 24 and np.abs(drawn - mine).mean() < 5, f"{name}'s tile, step {t}"
            for j, other in enumerate(agent_tiles):  # where two labels differ, the pixels are this one's
                where = np.abs(mine - other).sum(axis=2) > 150
                if j != i and where.any():
                    assert np.abs(drawn - mine)[where].mean() * 4 < np.abs(drawn - other)[where].mean(), (name, j)
            body = AGENT_COLORS[role][0].astype(int)
            disc = drawn[2:CELL // 4, CELL // 2 - 2:CELL // 2 + 2]  # the top of the disc, above its label
            assert (np.abs(disc - body).sum(axis=2) <= 24).all(), f"{name} is drawn in the {role}s' color"
    panel = frames[0][:height - 60, board_w:]
    assert bars(panel) == cfg.num_colors * len(believers), "one chart (a bar per color) per agent with beliefs"
    first = next(episode_frames(replay, cell=CELL))[:, board_w:]  # the same frame before the GIF's palette
    for i, name in enumerate(cfg.agent_names):
        label = f"{cfg.symbols[i]} ({name})"
        assert text_at(first, f"{label} +0"), f"{label}'s score is listed"
        assert text_at(first, f"{label} belief") == (name in believers), f"{label}'s belief chart"
    below = frames[0][board_h:, :board_w].astype(int)  # the GIF's shared palette may move a color by a level or two
    assert (np.abs(below - PANEL_BG) <= 4).all(), "below the board, the panel's background"


# ------------------------------------------------------------ the 3D viewer
@pytest.fixture()
def team_viewer(tmp_path):
    folder = tmp_path / "replays"
    folder.mkdir()
    save(team_replay(2, 2), folder / "team.replay.json")
    viewer = ReplayViewer(folder, port=0)
    yield viewer
    viewer.stop()


def test_the_viewer_draws_every_agent_in_its_roles_color_with_its_label(team_viewer):
    tab = TabView(team_viewer, team_viewer.server)
    data = tab.data
    assert list(tab.grid.agents) == ["leader_0", "leader_1", "follower_0", "follower_1"]
    assert {name: label.text for name, label in tab.grid.labels.items()} == {
        "leader_0": "L1 (leader_0)", "leader_1": "L2 (leader_1)", "follower_0": "F1 (follower_0)",
        "follower_1": "F2 (follower_1)"}
    for name, role in zip(data["agent_names"], data["roles"]):
        assert tuple(tab.grid.agents[name].color) == tuple(int(v) for v in np.minimum(AGENT_COLORS[role][0], 235))
    for t in (0, 17, 30):
        tab.slider.value = t
        for name in data["agent_names"]:
            r, c = divmod(data["boards"][t][name], data["width"])
            assert np.allclose(tab.grid.agents[name].position, (c + 0.5, data["height"] - r - 0.5, 0.45))
    assert [chart.title for chart in tab.charts.values()] == ["F1 (follower_0)'s goal probabilities",
                                                             "F2 (follower_1)'s goal probabilities"]
    for name, chart in tab.charts.items():
        x, *curves = chart.data
        assert chart.axes[2]["splits"] == (30.0,)  # the cursor: an axis at the slider's step, not a series
        assert np.allclose(np.stack(curves, axis=1)[:30], data["goal_probs"][name])
    scores = data["boards"][30]["scores"]
    assert f"(L1 {scores[0]:+.0f}, L2 {scores[1]:+.0f}, F1 {scores[2]:+.0f}, F2 {scores[3]:+.0f})" in tab.info.content
    assert "F1 (follower_0) believes: red" in tab.info.content and "F2 (follower_1) believes: red" in tab.info.content


def test_the_viewers_standalone_export_labels_every_agent_and_charts_each_follower():
    data = timeline(team_replay(2, 2))
    recording, buffers = read_recording(standalone_html(data, "team.replay.json"))
    messages = recording["messages"]
    labels = {m["props"]["text"] for _, m in messages if m["type"] == "LabelMessage"}
    assert {"L1 (leader_0)", "L2 (leader_1)", "F1 (follower_0)", "F2 (follower_1)"} <= labels
    assert {"F1 (follower_0)'s goal probabilities", "F2 (follower_1)'s goal probabilities"} <= labels
    curves = {m["name"]: m["props"]["points"] for _, m in messages if m["type"] == "LineSegmentsMessage"}
    bottoms = []
    for name in ("follower_0", "follower_1"):
        for k, color in enumerate(data["colors"]):
            placeholder = curves[f"/panel/chart/{name}/{color}"]
            segments = np.frombuffer(buffers[placeholder["__binary_index"]], dtype=placeholder["dtype"])
            segments = segments.reshape(-1, 2, 3)
            assert len(segments) == data["steps"] - 1
            if k == 0:
                bottoms.append(segments[:, :, 1].min())
    assert bottoms[1] < bottoms[0] - data["height"] / 2, "the second chart stands below the first"


# ------------------------------------------------------------ the web replay player
def board_pixel(page, x: float, y: float) -> str:
    return page.locator("#board").evaluate(
        f"c => '#' + [...c.getContext('2d').getImageData({int(x)}, {int(y)}, 1, 1).data.slice(0, 3)]"
        ".map(v => v.toString(16).padStart(2, '0')).join('')")


def test_the_replay_player_draws_every_agent_with_its_label_and_a_chart_per_follower(server, browser):
    save(team_replay(2, 2), server.replays_dir / "team22.replay.json")
    save(team_replay(1, 2, believers=("follower_1",), seed=3), server.replays_dir / "team12.replay.json")
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    try:
        page.goto(server.url + "/replay?id=team22&step=12")
        board = page.locator("#board")
        expect(board).to_have_attribute("data-step", "12", timeout=60_000)  # timelines come from a worker
        data = server.get("/api/replays/team22/timeline")[0]
        assert data["agent_names"] == ["leader_0", "leader_1", "follower_0", "follower_1"]
        names, state = data["agent_names"], data["boards"][12]
        # every agent listed with its label, name, policy and score
        rows = page.locator("#agent-scores [data-agent]")
        expect(rows).to_have_count(4)
        assert rows.evaluate_all("rs => rs.map(r => r.dataset.agent)") == names
        assert page.locator("#agent-scores .agent-badge").all_text_contents() == ["L1", "L2", "F1", "F2"]
        assert rows.nth(2).text_content().startswith("F1 follower_0 (random)")
        for i, name in enumerate(names):
            expect(page.locator(f"#score-{name}")).to_have_text(f"{state['scores'][i]:.0f}")
        # the board names every agent and where it stands ...
        described = board.get_attribute("aria-label")
        cell = (520 - 8) // data["width"]
        images = []
        for agent in data["look"]["agents"]:
            r, c = divmod(state[agent["name"]], data["width"])
            assert f"{agent['symbol']} ({agent['name']}) at row {r + 1}, column {c + 1}" in described
            assert board.get_attribute(f"data-{agent['name']}") == str(state[agent["name"]])
            # ... and draws it: a disc in its role's color, its label in the ink color inside
            x, y = 4 + c * cell + cell / 2, 4 + r * cell + cell / 2
            assert board_pixel(page, x, y - cell * 0.35) == agent["body"], agent["name"]
            images.append(board.evaluate(f"c => Array.from(c.getContext('2d').getImageData("
                                         f"{4 + c * cell + 4}, {4 + r * cell + 4}, {cell - 8}, {cell - 8}).data)"))
            ink = np.array([int(agent["ink"][k:k + 2], 16) for k in (1, 3, 5)])
            pixels = np.array(images[-1]).reshape(-1, 4)[:, :3]
            assert (np.abs(pixels - ink).sum(axis=1) < 30).sum() > 20, f"{agent['symbol']}'s label is drawn"
        assert len({tuple(i) for i in images[:2]}) == 2 and len({tuple(i) for i in images[2:]}) == 2, \
            "L1 and L2, F1 and F2 carry different labels"
        # one group of belief bars and one chart per follower with beliefs
        groups = page.locator(".belief-group")
        expect(groups).to_have_count(2)
        assert groups.locator("h3").all_text_contents() == ["F1 (follower_0) believes", "F2 (follower_1) believes"]
        expect(page.locator(".belief-row")).to_have_count(6)
        for j, name in enumerate(("follower_0", "follower_1")):
            shown = groups.nth(j).locator(".belief-value").all_text_contents()
            assert shown == [f"{p:.2f}" for p in data["goal_probs"][name][12]]
        charts = page.locator("canvas.episode-chart")
        expect(charts).to_have_count(2)
        assert charts.evaluate_all("cs => cs.map(c => [c.dataset.agent, c.dataset.cursor])") == [
            ["follower_0", "12"], ["follower_1", "12"]]
        assert page.locator(".chart-title").all_text_contents() == ["F1 (follower_0): goal probabilities",
                                                                    "F2 (follower_1): goal probabilities"]
        expect(page.locator("#branch-controls")).to_be_hidden()  # branching continues a 1:1 team's follower
        # the cursor moves every chart; clicking the second one jumps there
        page.keyboard.press("ArrowRight")
        expect(board).to_have_attribute("data-step", "13")
        assert charts.evaluate_all("cs => cs.map(c => c.dataset.cursor)") == ["13", "13"]
        box = charts.nth(1).bounding_box()
        charts.nth(1).click(position={"x": box["width"] - 9, "y": box["height"] / 2})
        expect(board).to_have_attribute("data-step", str(data["steps"]))
        expect(page.locator("#agent-scores .row").first).to_contain_text("leader_0")

        page.goto(server.url + "/replay?id=" + quote("team12"))  # only follower_1 logged beliefs
        expect(board).to_have_attribute("data-step", "0", timeout=60_000)
        assert page.locator("#agent-scores .agent-badge").all_text_contents() == ["L1", "F1", "F2"]
        expect(page.locator(".belief-group")).to_have_count(1)
        expect(page.locator(".belief-group h3")).to_have_text("F2 (follower_1) believes")
        expect(page.locator("canvas.episode-chart")).to_have_count(1)
        expect(page.locator("canvas.episode-chart")).to_have_attribute("data-agent", "follower_1")
        assert errors == []
    finally:
        page.close()


def test_a_one_to_one_replay_keeps_its_page(server, browser):
    page = browser.new_page()
    try:
        page.goto(server.url + "/replay?id=" + quote("released--default--astar+bayes_seed2026"))
        expect(page.locator("#board")).to_have_attribute("data-step", "0", timeout=60_000)
        expect(page.locator("#leader-label")).to_have_text("astar")
        expect(page.locator("#follower-label")).to_have_text("bayes")
        expect(page.locator("#agent-scores .agent-badge")).to_have_count(0)
        expect(page.locator(".belief-group")).to_have_count(0)
        expect(page.locator("#belief > .belief-row")).to_have_count(3)  # the follower's bars, as ever
        expect(page.locator("canvas.episode-chart")).to_have_count(1)
        expect(page.locator(".chart-title")).to_have_count(0)
        expect(page.locator("#branch-controls")).to_be_visible()
        described = page.locator("#board").get_attribute("aria-label")
        assert "L (leader) at row" in described and "F (follower) at row" in described
    finally:
        page.close()


def test_the_replay_list_names_each_roles_policies_and_the_team(tmp_path):
    from server.replays import summarize

    replay = team_replay(2, 1)
    replay.agents = {"leader_0": {"policy": "human"}, "leader_1": {"policy": "human", "replaced_by": "astar"},
                     "follower_0": {"policy": "bayes"}}
    save(replay, tmp_path / "a.replay.json")
    summary = summarize(tmp_path / "a.replay.json", "a", "recorded")
    assert (summary["leader"], summary["follower"], summary["team"]) == ("human", "bayes", "2:1")
    replay.agents["leader_1"] = {"policy": "astar"}
    save(replay, tmp_path / "b.replay.json")
    assert summarize(tmp_path / "b.replay.json", "b", "recorded")["leader"] == "human+astar"


def test_branching_a_team_replay_is_refused_with_its_reason():
    from colorgrid.replay.branch import branch
    from colorgrid.replay import ReplayError

    with pytest.raises(ReplayError, match="only 1:1 replays can be branched; this one's team is 2:1"):
        branch(team_replay(2, 1), 5, "copy")
