"""Replay format: round trip, verification, corruption, atomic writes, import, export."""

import json
import os
import subprocess
import sys

import imageio.v2 as imageio
import numpy as np
import pytest

from colorgrid import BatchEnv, EnvConfig
from colorgrid.evaluate import record_batch
from colorgrid.replay.export import export
from colorgrid.policies import make_policy
from colorgrid.render import PALETTE
from colorgrid.replay import ReplayError, import_frames, load, replay_states, save, verify
from colorgrid.replay.format import FORMAT_VERSION, checksum
from colorgrid.rollout import run_episodes

CONFIG = EnvConfig(horizon=40)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("replays")
    leader, follower = make_policy("astar"), make_policy("bayes")
    batch = run_episodes(CONFIG, leader, follower, 3, 11, record_hashes=True)
    paths = record_batch(batch, "astar", "bayes", leader, follower, out, "eval")
    return batch, paths


def test_round_trip_resimulates_the_original(recorded):
    batch, paths = recorded
    for e, path in enumerate(paths):
        replay = load(path)
        assert replay.seed == int(batch.seeds[e]) and replay.kind == "actions"
        states = replay_states(replay)
        assert [s.state_hash(0) for s in states] == list(batch.state_hashes[:, e])
        assert replay.actions == batch.actions[:, e].tolist()
        assert np.allclose(replay.goal_probs["follower"], batch.goal_probs[1][:, e], atol=1e-5)
        final = replay.final()
        assert final["team_score"] == pytest.approx(float(batch.team_reward[:, e].sum()))
        assert final["follower_score"] == pytest.approx(float(states[-1].score[0, 1]))
        assert verify(replay).ok


def test_verify_reports_the_first_step_after_a_flipped_action(recorded, tmp_path):
    _, paths = recorded
    replay = load(paths[0])
    states = replay_states(replay)
    for t, action in enumerate(replay.actions):  # find a step where another leader action changes the state
        trial = load(paths[0])
        trial.actions[t][0] = (action[0] + 1) % 4
        result = verify(trial)
        if not result.ok:
            assert result.first_bad_step == t + 1
            assert f"state hash mismatch at step {t + 1} (the state after step {t})" in result.message
            break
    else:
        pytest.fail("no flipped action changed the trajectory")
    assert states[0].state_hash(0) == replay.state_hashes[0]


def test_a_corrupted_byte_is_caught(recorded, tmp_path):
    _, paths = recorded
    raw = bytearray(paths[0].read_bytes())
    at = raw.index(b'"team_reward":[') + len(b'"team_reward":[')
    raw[at] = ord("7") if raw[at] != ord("7") else ord("3")  # still valid JSON, different content
    bad = tmp_path / "bad.replay.json"
    bad.write_bytes(bytes(raw))
    with pytest.raises(ReplayError, match=r"bad.replay.json: checksum mismatch"):
        load(bad)
    truncated = tmp_path / "cut.replay.json"
    truncated.write_bytes(paths[0].read_bytes()[:500])
    with pytest.raises(ReplayError, match=r"cut.replay.json: not valid JSON \(truncated or corrupt\?\)"):
        load(truncated)


def test_newer_versions_missing_fields_and_non_replays_get_clear_errors(recorded, tmp_path):
    _, paths = recorded
    doc = json.loads(paths[0].read_text())

    def write(d, name):
        d = {k: v for k, v in d.items() if k != "checksum"}
        d["checksum"] = checksum(d)
        p = tmp_path / name
        p.write_text(json.dumps(d))
        return p

    newer = dict(doc, format_version=FORMAT_VERSION + 1)
    with pytest.raises(ReplayError, match=rf"format version {FORMAT_VERSION + 1} is newer than this colorgrid reads"):
        load(write(newer, "newer.replay.json"))
    missing = {k: v for k, v in doc.items() if k != "penalty_coef"}
    with pytest.raises(ReplayError, match=r"required field 'penalty_coef' is missing"):
        load(write(missing, "missing.replay.json"))
    bad_actions = json.loads(json.dumps(doc))
    bad_actions["steps"]["actions"][3] = [9, 0]
    with pytest.raises(ReplayError, match=r"steps.actions must be \[T\]\[2\] integers in \[0, 4\)"):
        load(write(bad_actions, "actions.replay.json"))
    bad_config = json.loads(json.dumps(doc))
    bad_config["config"]["height"] = 1
    with pytest.raises(ReplayError, match=r"invalid config: EnvConfig.height must be"):
        load(write(bad_config, "config.replay.json"))
    other = tmp_path / "other.replay.json"
    other.write_text('{"hello": 1}')
    with pytest.raises(ReplayError, match="not a ColorGrid replay"):
        load(other)
    with pytest.raises(ReplayError, match="nowhere.replay.json: no such file"):
        load(tmp_path / "nowhere.replay.json")


def test_atomic_write_leaves_no_file_when_interrupted(recorded, tmp_path, monkeypatch):
    _, paths = recorded
    replay = load(paths[0])
    target = tmp_path / "atomic.replay.json"

    def crash(fd):
        raise KeyboardInterrupt("power cut")

    monkeypatch.setattr(os, "fsync", crash)
    with pytest.raises(KeyboardInterrupt):
        save(replay, target)
    assert not target.exists() and list(tmp_path.iterdir()) == []
    monkeypatch.undo()
    save(replay, target)
    before = target.read_bytes()
    monkeypatch.setattr(os, "fsync", crash)
    with pytest.raises(KeyboardInterrupt):
        save(load(paths[1]), target)
    assert target.read_bytes() == before, "a failed rewrite keeps the old file intact"


def test_import_of_a_frames_only_trajectory(tmp_path):
    env = BatchEnv(CONFIG, num_envs=1, seed=4)
    obs, _ = env.reset()
    planes, goals, states = [obs["observation"][0].copy()], [obs["goal_info"][0, 0].copy()], [env.state.copy()]
    rng = np.random.default_rng(0)
    for _ in range(20):
        obs, *_ = env.step(rng.integers(0, 4, (1, 2)))
        planes.append(obs["observation"][0].copy())
        goals.append(obs["goal_info"][0, 0].copy())
        states.append(env.state.copy())
    np.save(tmp_path / "trajectory_0.npy", np.stack(planes))
    np.save(tmp_path / "goal_info_0.npy", np.stack(goals))
    out = tmp_path / "imported.replay.json"
    result = subprocess.run([sys.executable, "-m", "colorgrid_apps", "replay", "import", str(tmp_path / "trajectory_0.npy"),
                             str(tmp_path / "goal_info_0.npy"), "--out", str(out), "--set", "horizon=40"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    replay = load(out)
    assert replay.kind == "frames" and replay.num_steps == 20
    for t, state in enumerate(replay_states(replay)):
        assert (state.agent_cell == states[t].agent_cell).all()
        assert (state.block_colors(CONFIG) == states[t].block_colors(CONFIG)).all()
        assert state.goal[0] == states[t].goal[0]
    with pytest.raises(ReplayError, match=r"trajectory must have shape \[T, 5, 32, 32\]"):
        import_frames(CONFIG, np.zeros((3, 4, 32, 32)), np.zeros((3, 3)))


@pytest.mark.parametrize("fmt", ["gif", "mp4"])
def test_export_frame_count_size_and_belief_panel(recorded, tmp_path, fmt):
    _, paths = recorded
    replay = load(paths[0])
    out = export(replay, tmp_path / f"episode.{fmt}", fmt, fps=10, cell=8)
    frames = [f for f in imageio.get_reader(out)]
    assert len(frames) == replay.num_steps + 1
    board_h = 22 + 32 * 8 + 8
    assert frames[0].shape[0] == board_h and frames[0].shape[1] == 32 * 8 + 8 + 230
    # The first frame's panel shows the follower's uniform prior: three bars a third full.
    panel = frames[0][: board_h - 45, 32 * 8 + 8:, :3].astype(int)  # above the episode timeline
    for k in range(3):
        match = (np.abs(panel - PALETTE[k].astype(int)).sum(axis=2) < 40).sum(axis=1)
        assert match.max() == pytest.approx(50, abs=3), f"belief bar for color {k}"
    short = export(replay, tmp_path / f"short.{fmt}", fmt, start=5, end=9, cell=8)
    assert len([f for f in imageio.get_reader(short)]) == 5


def test_export_errors(recorded, tmp_path):
    _, paths = recorded
    replay = load(paths[0])
    with pytest.raises(ValueError, match=r"unknown format 'avi'; choose one of \['gif', 'mp4'\]"):
        export(replay, tmp_path / "x.avi", "avi")
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(ValueError, match="cannot write to"):
        export(replay, blocker / "x.gif", "gif")
    with pytest.raises(ValueError, match=r"--start/--end must satisfy 0 <= start <= end <= 40"):
        export(replay, tmp_path / "x.gif", "gif", start=30, end=50)
    assert not (tmp_path / "x.gif").exists()


def test_cli_verify_names_bad_files_and_exits_nonzero(recorded, tmp_path):
    _, paths = recorded
    bad = tmp_path / "bad.replay.json"
    bad.write_bytes(paths[0].read_bytes()[:-20])
    result = subprocess.run([sys.executable, "-m", "colorgrid_apps", "replay", "verify", str(paths[1]), str(bad)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert f"{paths[1]}: ok" in result.stdout
    assert f"{bad}: error: not valid JSON" in result.stdout


def test_look_names_the_pictures_colors_and_the_timeline_carries_it(recorded):
    from colorgrid.config import AGENTS, SYMBOLS
    from colorgrid.render import AGENT_COLORS, FLOOR, GRID_LINE, hex_color, look
    from colorgrid.replay.timeline import timeline

    full = look()
    assert full["palette"] == [hex_color(rgb) for rgb in PALETTE] and full["palette"][0] == "#dc322f"
    assert (full["floor"], full["grid"]) == (hex_color(FLOOR), hex_color(GRID_LINE))
    assert full["agents"] == [{"name": name, "role": name, "symbol": SYMBOLS[i],
                               "body": hex_color(AGENT_COLORS[name][0]), "ink": hex_color(AGENT_COLORS[name][1])}
                              for i, name in enumerate(AGENTS)]
    assert full["agents"][0] == {"name": "leader", "role": "leader", "symbol": "L", "body": "#191919",
                                 "ink": "#ffffff"}
    _, paths = recorded
    data = timeline(load(paths[0]))
    assert data["look"] == look(CONFIG) and data["look"]["palette"] == full["palette"][:CONFIG.num_colors]
    assert all(set(board) >= set(AGENTS) for board in data["boards"])


def test_the_blocks_string_is_written_and_read_by_one_pair_of_functions():
    from colorgrid.replay.blocks import decode_blocks, encode_blocks

    colors = np.array([-1, -1, 0, -1, 2, 7, 1])
    assert encode_blocks(colors) == "..0.271"
    assert decode_blocks("..0.271").tolist() == colors.tolist()
    assert decode_blocks(encode_blocks(np.full(5, -1))).tolist() == [-1] * 5
