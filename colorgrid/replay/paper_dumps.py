"""The paper code's trajectory dumps as frames replays: one file, or a whole ``trajectories/<run>`` folder.

``run_ppo.py`` writes each dumped episode as two ``.npy`` files: ``trajectory_iteration={I}_env={E}.npy``, the
leader's observations ``[T, 5, 32, 32]`` float (planes RED, BLUE, GREEN, leader, follower, indexed ``[x, y]``),
and ``goal_info_iteration={I}_env={E}.npy``, its goal one-hots ``[T, 3]`` (RED, BLUE, GREEN). They are mapped
through ``colorgrid.paper_format`` (so the paper's blue is our blue), and the block density is read from the
frames (``colorgrid.replay.frames``): its default 0.05 (17 of each color) and its experiments' 0.10 (34) both
import without a setting.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.paper_format import PAPER_SOURCE, colors_from_paper, observation_from_paper
from colorgrid.replay.format import SUFFIX, Replay, ReplayError, save
from colorgrid.replay.frames import describe_frames, import_frames
from colorgrid.replay.index import index_entry, write_index

TRAJECTORY_NAME = re.compile(r"trajectory_iteration=(\d+)_env=(\d+)\.npy")
"""The name ``run_ppo.py`` gives a dump's observations."""
LAYOUTS = ("paper", "colorgrid")
"""How a trajectory's planes are laid out: the paper code's dumps, or this project's observations."""


@dataclass(frozen=True)
class Dump:
    """One dumped episode: its two files, and which iteration and env of the run it is."""

    trajectory: Path
    goal_info: Path
    iteration: int
    env: int

    @property
    def stem(self) -> str:
        """Its replay's name: ``iteration0_env3`` (replay ids take no ``=``)."""
        return f"iteration{self.iteration}_env{self.env}"


def paper_dump(trajectory: Path) -> Dump | None:
    """The dump whose observations are the file ``trajectory`` (its goal one-hots beside it), or None when the
    name is not one ``run_ppo.py`` writes."""
    match = TRAJECTORY_NAME.fullmatch(trajectory.name)
    if match is None:
        return None
    iteration, env = map(int, match.groups())
    return Dump(trajectory, trajectory.with_name(f"goal_info_iteration={iteration}_env={env}.npy"), iteration, env)


def folder_dumps(folder: Path) -> list[Dump]:
    """Every dump in ``folder`` (a ``trajectories/<run>`` folder of ``run_ppo.py``), paired by iteration and env,
    in that order; a folder without any, or a trajectory without its goal one-hots, raises ``ReplayError``."""
    if not folder.is_dir():
        raise ReplayError(folder, "is not a folder" if folder.exists() else "no such folder")
    dumps = sorted((d for d in map(paper_dump, folder.iterdir()) if d is not None), key=lambda d: (d.iteration, d.env))
    if not dumps:
        hint = " (compressed: gunzip them first)" if any(folder.glob("trajectory_*.npy.gz")) else ""
        raise ReplayError(folder, f"holds no dumps of the paper's run_ppo.py (trajectory_iteration=I_env=E.npy with "
                                  f"goal_info_iteration=I_env=E.npy){hint}")
    for dump in dumps:
        if not dump.goal_info.is_file():
            raise ReplayError(dump.trajectory, f"has no goal one-hots beside it: {dump.goal_info.name} is missing")
    return dumps


def read_array(path: Path, what: str) -> np.ndarray:
    """A ``.npy`` file's array; a file that is not one raises ``ReplayError`` saying what was expected."""
    if path.suffix == ".gz":
        raise ReplayError(path, f"is compressed: gunzip it first ({what})")
    try:
        array = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ReplayError(path, f"no such file ({what})") from None
    except (OSError, ValueError) as err:
        problem = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ReplayError(path, f"is not a .npy array ({what}): {problem}") from None
    if not isinstance(array, np.ndarray) or not (np.issubdtype(array.dtype, np.number) or array.dtype == bool):
        raise ReplayError(path, f"does not hold a numeric array ({what})")
    return array


def import_trajectory(config: EnvConfig, trajectory: Path, goal_info: Path, layout: str,
                      fixed_density: bool = False, meta: dict | None = None) -> Replay:
    """A frames replay of one dumped episode: ``trajectory`` ``[T, C+A, H, W]`` and ``goal_info`` ``[T, C]`` in
    ``layout`` (``paper``: mapped from the paper code's; ``colorgrid``: as they are). The block density comes from
    the frames (``import_frames``). Anything wrong raises ``ReplayError`` naming the file."""
    planes = read_array(trajectory, "observations [T, planes, H, W]")
    return import_arrays(config, planes, trajectory, goal_info, layout, fixed_density, meta)


def import_arrays(config: EnvConfig, planes: np.ndarray, trajectory: Path, goal_info: Path, layout: str,
                  fixed_density: bool = False, meta: dict | None = None) -> Replay:
    """``import_trajectory`` of observations already read from ``trajectory``."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout {layout!r}: one of {list(LAYOUTS)}")
    goals = read_array(goal_info, "goal one-hots [T, colors]")
    if layout == "paper":
        if planes.ndim != 4 or goals.ndim != 2:
            raise ReplayError(trajectory, f"is not a dump of the paper's run_ppo.py: its observations are "
                                          f"[T, 5, X, Y] and its goal one-hots [T, 3], got {list(planes.shape)} and "
                                          f"{list(goals.shape)}")
        try:
            planes, goals = observation_from_paper(planes), colors_from_paper(goals)
        except (ValueError, IndexError) as err:
            raise ReplayError(trajectory, f"is not a dump of the paper's run_ppo.py: {err}") from None
    meta = {"imported_from": trajectory.name, "goal_info_from": goal_info.name, "layout": layout, **(meta or {})}
    if layout == "paper":
        meta["code"] = PAPER_SOURCE
    try:
        return import_frames(config, planes, goals, meta=meta, fixed_density=fixed_density)
    except ReplayError as err:
        raise ReplayError(trajectory, err.problem) from None


def import_folder(config: EnvConfig, folder: Path, out: Path, generated_by: str,
                  fixed_density: bool = False) -> list[tuple[Path, Replay]]:
    """Every dump of ``folder`` (``folder_dumps``) as a frames replay ``out/iteration{I}_env{E}.replay.json``,
    with ``out/index.json`` listing them (``generated_by``: the command). Every dump is read and checked before
    anything is written; dumps of different shapes raise ``ReplayError``. Returns the written paths and replays."""
    dumps = folder_dumps(folder)
    replays, first = [], None
    for dump in dumps:
        planes = read_array(dump.trajectory, "observations [T, 5, X, Y]")
        first = first or (dump.trajectory.name, planes.shape)
        if planes.shape != first[1]:
            raise ReplayError(folder, f"mixes dumps of different shapes: {dump.trajectory.name} is "
                                      f"{list(planes.shape)}, {first[0]} {list(first[1])}; import one run's folder")
        replays.append(import_arrays(config, planes, dump.trajectory, dump.goal_info, "paper", fixed_density,
                                     meta={"run": folder.name, "iteration": dump.iteration, "env": dump.env}))
    out.mkdir(parents=True, exist_ok=True)
    written, entries = [], []
    for dump, replay in zip(dumps, replays):
        path = save(replay, out / f"{dump.stem}{SUFFIX}")
        written.append((path, replay))
        entries.append(index_entry(replay, path.name, run=folder.name, iteration=dump.iteration, env=dump.env,
                                   trajectory=dump.trajectory.name, goal_info=dump.goal_info.name,
                                   description=f"Iteration {dump.iteration}, env {dump.env} of the paper code's run "
                                               f"{folder.name}: {describe_frames(replay)}."))
    write_index(out, entries, generated_by)
    return written
