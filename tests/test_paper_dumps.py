"""The paper code's trajectory dumps imported as replays (``colorgrid replay import``), and env settings named
``env.KEY`` on every command.

The dumps (``tests/data/paper/``, written by the paper's own ``run_ppo.py``; see
``/work/shared/paper_artifacts/README.md``) are one episode at its experiments' block density 0.10 (34 blocks of
each color) and two at its code's default 0.05 (17 of each, ``density05/``). What the states should hold is read
from the dumps here with the paper's facts written out (planes RED, BLUE, GREEN, leader, follower, indexed
``[x, y]`` with y upward), not through the mapping under test.
"""

import gzip
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from colorgrid.config import COLOR_NAMES, EnvConfig
from colorgrid.replay import ReplayError, import_frames, load, replay_states, save
from colorgrid_apps.cli import main
from server.replays import ReplayCatalogue, summarize
from tests.conftest import ROOT

DATA = ROOT / "tests" / "data" / "paper"
PAPER_COLOR_NAMES = ("red", "blue", "green")
"""The paper code's color planes 0, 1, 2 (``color_maze.IDs``)."""
DUMPS = {"density 0.10": ("", 0, 34, 0.10), "density 0.05, env 0": ("density05", 0, 17, 0.05),
         "density 0.05, env 3": ("density05", 3, 17, 0.05)}
"""Each dump: its folder in tests/data/paper, its env, the blocks of each color it holds, the density giving them."""


def unpack(folder: str, env: int, to: Path) -> Path:
    """A dump's two files as ``run_ppo.py`` wrote them (the trajectory gunzipped) in ``to``; the trajectory's path."""
    to.mkdir(parents=True, exist_ok=True)
    trajectory = to / f"trajectory_iteration=0_env={env}.npy"
    trajectory.write_bytes(gzip.decompress((DATA / folder / f"{trajectory.name}.gz").read_bytes()))
    shutil.copy(DATA / folder / f"goal_info_iteration=0_env={env}.npy", to)
    return trajectory


def expected_board(planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """From a dump's frames ``[T, 5, X, Y]``: each cell's block color by the paper's name as its own picture draws
    it (x to the right, y upward; row 0 at the top), ``[T, H, W]`` ("" for none), and the agents' cells
    ``[T, 2]`` (row * W + col)."""
    T, _, X, Y = planes.shape
    names = np.full((T, Y, X), "", dtype=object)
    agents = np.zeros((T, 2), dtype=np.int64)
    for t in range(T):
        for k, name in enumerate(PAPER_COLOR_NAMES):
            for x, y in np.argwhere(planes[t, k] == 1):
                names[t, Y - 1 - y, x] = name
        for i in range(2):
            (x, y), = np.argwhere(planes[t, 3 + i] == 1)
            agents[t, i] = (Y - 1 - y) * X + x
    return names, agents


def assert_replay_shows_the_dump(replay, trajectory: Path) -> None:
    """Every cell of every state holds the dump's block, named as the paper names its color; the agents and the
    goal (by name) are the dump's."""
    planes = np.load(trajectory)
    goals = np.load(str(trajectory).replace("trajectory_", "goal_info_"))
    names, agents = expected_board(planes)
    config = replay.config
    states = replay_states(replay)
    assert len(states) == len(planes)
    for t, state in enumerate(states):
        colors = state.block_colors(config)[0]
        shown = np.where(colors >= 0, np.array(COLOR_NAMES, dtype=object)[colors], "")
        assert (shown == names[t]).all(), f"frame {t}: {np.argwhere(shown != names[t])[:3].tolist()}"
        assert state.agent_cell[0].tolist() == agents[t].tolist(), f"frame {t}"
        assert COLOR_NAMES[replay.frames["goal"][t]] == PAPER_COLOR_NAMES[int(goals[t].argmax())], f"frame {t}"


@pytest.mark.parametrize("dump", DUMPS)
def test_a_dump_imports_at_its_own_density_with_the_papers_color_names(tmp_path, capsys, dump):
    folder, env, per_color, density = DUMPS[dump]
    trajectory = unpack(folder, env, tmp_path / "run")
    out = tmp_path / "episode.replay.json"
    assert main(["replay", "import", str(trajectory), "--out", str(out)]) == 0  # no --set, no GOAL_INFO
    assert f"{per_color} blocks of each color (block density {density:g})" in capsys.readouterr().out
    replay = load(out)
    assert replay.kind == "frames" and replay.num_steps == 127
    assert replay.config.blocks_per_color == per_color and replay.config.block_density == density
    assert replay.meta["layout"] == "paper" and replay.meta["imported_from"] == trajectory.name
    assert_replay_shows_the_dump(replay, trajectory)


def test_a_folder_is_paired_by_iteration_and_env_and_listed_with_its_index(tmp_path, capsys):
    run = tmp_path / "trajectories" / "density05"
    for env in (3, 0):
        unpack("density05", env, run)
    (run / "notes.txt").write_text("not a dump")  # other files are left alone
    out = tmp_path / "replays" / "density05"
    assert main(["replay", "import", str(run), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.count("wrote ") == 3 and f"{out / 'index.json'}: 2 replays" in printed
    index = json.loads((out / "index.json").read_text())
    assert index["generated_by"] == f"colorgrid replay import {run} --out {out}"
    entries = index["replays"]
    assert [(e["iteration"], e["env"]) for e in entries] == [(0, 0), (0, 3)]
    for entry in entries:
        assert entry["trajectory"] == f"trajectory_iteration=0_env={entry['env']}.npy"
        assert entry["goal_info"] == f"goal_info_iteration=0_env={entry['env']}.npy"
        assert entry["file"] == f"iteration0_env{entry['env']}.replay.json" and entry["run"] == "density05"
        assert entry["config"]["block_density"] == 0.05 and "17 blocks of each color" in entry["description"]
        assert_replay_shows_the_dump(load(out / entry["file"]), run / entry["trajectory"])
    # The replay browser's listing finds every file of the index, and each loads.
    listed = ReplayCatalogue(tmp_path / "replays", None).scan()
    assert sorted(listed) == [f"density05--iteration0_env{e['env']}" for e in entries]
    for replay_id, entry in listed.items():
        summary = summarize(entry.path, replay_id, "recorded")
        assert "error" not in summary and summary["kind"] == "frames" and summary["steps"] == 127
    assert main(["replay", "verify", str(out)]) == 0


def test_a_frames_replay_whose_density_does_not_fit_its_frames_does_not_load(tmp_path):
    """A file imported before the density was read from the frames drew some blocks in another color; now it is
    refused, naming the count."""
    trajectory = unpack("density05", 0, tmp_path)
    out = tmp_path / "episode.replay.json"
    assert main(["replay", "import", str(trajectory), "--out", str(out)]) == 0
    replay = load(out)
    replay.config = replay.config.replace(block_density=0.10)
    save(replay, out)
    with pytest.raises(ReplayError, match=r"frames.blocks\[0\] holds 17 red blocks, but the config's block_density "
                                          r"0.1 gives 34 of each color"):
        load(out)


def frames_of(planes_per_color: list[int]) -> np.ndarray:
    """Two frames in this project's layout with ``planes_per_color[k]`` blocks of color k (1:1 team, 32x32)."""
    planes = np.zeros((2, 5, 32, 32), dtype=np.uint8)
    cells = iter(range(2, 1024))
    for k, count in enumerate(planes_per_color):
        for _ in range(count):
            cell = next(cells)
            planes[:, k, cell // 32, cell % 32] = 1
    planes[:, 3, 0, 0] = planes[:, 4, 0, 1] = 1
    return planes


def test_the_block_density_is_read_from_the_frames_or_refused_in_one_line():
    goal = np.eye(3)[[0, 0]]
    assert import_frames(EnvConfig(), frames_of([20, 20, 20]), goal).config.block_density == 0.06
    assert import_frames(EnvConfig(), frames_of([34, 34, 34]), goal).config.block_density == 0.1
    with pytest.raises(ReplayError, match="frame 0 holds 17 red, 16 green, 17 blue blocks; a replay's states hold "
                                          "the same number of each color"):
        import_frames(EnvConfig(), frames_of([17, 16, 17]), goal)
    with pytest.raises(ReplayError, match="block_density=0.1 gives 34 blocks of each color, but the frames hold 17: "
                                          "block_density=0.05 fits them"):
        import_frames(EnvConfig(), frames_of([17, 17, 17]), goal, fixed_density=True)
    changing = frames_of([17, 17, 17])
    changing[1, 0, 0, 2] = 0
    with pytest.raises(ReplayError, match="frame 1 holds 16 red, 17 green, 17 blue blocks, frame 0 17 of each"):
        import_frames(EnvConfig(), changing, goal)


def bad_dump(tmp_path: Path, case: str) -> tuple[list[str], str]:
    """The command's arguments for one kind of bad input, and what its one line must say."""
    run = tmp_path / "run"
    trajectory = unpack("density05", 0, run)
    out = ["--out", str(tmp_path / "out")]
    if case == "empty folder":
        return ["replay", "import", str(tmp_path / "empty"), *out], "holds no dumps of the paper's run_ppo.py"
    if case == "compressed folder":
        shutil.copy(DATA / "density05" / "trajectory_iteration=0_env=3.npy.gz", tmp_path / "empty")
        return ["replay", "import", str(tmp_path / "empty"), *out], "(compressed: gunzip them first)"
    if case == "not a .npy":
        trajectory.write_text("iteration,env\n0,0\n")
        return ["replay", "import", str(run), *out], "trajectory_iteration=0_env=0.npy: is not a .npy array"
    if case == "not the paper's planes":
        np.save(trajectory, np.zeros((128, 4, 32, 32), dtype=np.float32))
        return ["replay", "import", str(run), *out], ("is not a dump of the paper's run_ppo.py: the paper's "
                                                      "observations have 5 planes")
    if case == "not 0/1":
        np.save(trajectory, np.load(trajectory) * 0.5)
        return ["replay", "import", str(run), *out], "hold only 0s and 1s"
    if case == "goal info missing":
        trajectory.with_name("goal_info_iteration=0_env=0.npy").unlink()
        return ["replay", "import", str(run), *out], "goal_info_iteration=0_env=0.npy is missing"
    if case == "goal info of another length":
        np.save(trajectory.with_name("goal_info_iteration=0_env=0.npy"), np.eye(3, dtype=np.float32)[[0] * 64])
        return ["replay", "import", str(run), *out], "goal info must have shape [128, 3]"
    if case == "mixed shapes":
        np.save(run / "trajectory_iteration=1_env=0.npy", np.load(trajectory)[:64])
        shutil.copy(run / "goal_info_iteration=0_env=0.npy", run / "goal_info_iteration=1_env=0.npy")
        return ["replay", "import", str(run), *out], ("mixes dumps of different shapes: "
                                                      "trajectory_iteration=1_env=0.npy is [64, 5, 32, 32]")
    if case == "a density that does not fit":
        return ["replay", "import", str(trajectory), "--out", str(tmp_path / "a.replay.json"),
                "--set", "env.block_density=0.1"], "the frames hold 17: block_density=0.05 fits them"
    if case == "a file without goal info":
        plain = trajectory.rename(run / "episode.npy")
        return ["replay", "import", str(plain), "--out", str(tmp_path / "a.replay.json")], \
            "give its goal one-hots (GOAL_INFO) too"
    if case == "a folder to a replay file":
        return ["replay", "import", str(run), "--out", str(tmp_path / "a.replay.json")], \
            "a folder for the replays and their index.json"
    raise AssertionError(case)


@pytest.mark.parametrize("case", ["empty folder", "compressed folder", "not a .npy", "not the paper's planes",
                                  "not 0/1", "goal info missing", "goal info of another length", "mixed shapes",
                                  "a density that does not fit", "a file without goal info",
                                  "a folder to a replay file"])
def test_bad_input_gets_one_line_and_exit_code_2(tmp_path, capsys, case):
    (tmp_path / "empty").mkdir()
    args, says = bad_dump(tmp_path, case)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("colorgrid replay import: error: ") and says in err, err
    assert not (tmp_path / "out").exists(), "nothing is written when any dump is bad"


def test_env_settings_are_env_keys_on_every_command(tmp_path, capsys):
    trajectory = unpack("density05", 0, tmp_path)
    for spelling in ("env.block_density=0.05", "block_density=0.05"):  # the bare key these commands took still works
        out = tmp_path / f"{spelling.split('=')[0]}.replay.json"
        assert main(["replay", "import", str(trajectory), "--out", str(out), "--set", spelling,
                     "--set", "env.asymmetric=false"]) == 0
        assert load(out).config.block_density == 0.05 and not load(out).config.asymmetric
    for spelling in ("env.horizon=8", "horizon=8"):
        assert main(["demo", "--quiet", "--set", spelling]) == 0
    assert main(["eval", "--episodes", "1", "--follower", "idle", "--set", "env.horizon=8", "--set",
                 "env.goal_reward=4"]) == 0
    capsys.readouterr()
    # colorgrid train never took a bare env key: it is refused in one line naming the right one.
    assert main(["train", "--set", "block_density=0.05", "--print-config"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "(did you mean env.block_density?)" in err, err
    assert main(["train", "--set", "env.block_density=0.05", "--print-config"]) == 0
    assert json.loads(capsys.readouterr().out)["env"]["block_density"] == 0.05
    assert main(["eval", "--set", "env.colour=red"]) == 2
    assert "unknown EnvConfig field 'env.colour'" in capsys.readouterr().err
