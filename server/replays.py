"""The replay catalogue served under /api/replays: ids only, never paths from the request.

Only regular files inside the two folders are listed: symbolic links (to files or folders)
are skipped, so nothing outside the replay folders is ever read. Summaries are made in the
worker processes (``server.jobs``) and cached by file version.
"""

from __future__ import annotations

import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from colorgrid.config import ROLES
from colorgrid.replay import ReplayError, load

ID_PATTERN = re.compile(r"^[A-Za-z0-9_.+-]{1,200}$")
SUFFIX = ".replay.json"
BATCH = 200  # files summarised per worker call


@dataclass
class Entry:
    id: str
    path: Path
    collection: str  # "recorded" or "released"
    mtime: float
    size: int
    summary: dict | None = None

    @property
    def problem(self) -> str | None:
        """Why the file cannot be used, or None."""
        return None if self.summary is None else self.summary.get("error")


class ReplayCatalogue:
    """Scans the recordings folder and the released set; caches each file's summary by version."""

    def __init__(self, recorded_dir: Path, released_dir: Path | None):
        self.roots = [("recorded", Path(recorded_dir))]
        if released_dir is not None:
            self.roots.append(("released", Path(released_dir)))
        self.cache: dict[Path, Entry] = {}

    def scan(self) -> dict[str, Entry]:
        """Every replay file by id (file system calls only: run it off the event loop). Entries whose
        file changed since the last scan come back with ``summary`` None."""
        out: dict[str, Entry] = {}
        for collection, root in self.roots:
            for path, info in regular_files(root):
                rel = path.relative_to(root).as_posix()[: -len(SUFFIX)]
                replay_id = ("released--" if collection == "released" else "") + rel.replace("/", "--")
                if not ID_PATTERN.match(replay_id):
                    continue
                cached = self.cache.get(path)
                if cached is None or (cached.mtime, cached.size) != (info.st_mtime, info.st_size):
                    cached = Entry(replay_id, path, collection, info.st_mtime, info.st_size)
                    self.cache[path] = cached
                out[replay_id] = cached
        for gone in set(self.cache) - {e.path for e in out.values()}:
            del self.cache[gone]
        return out

    def missing(self, entries: dict[str, Entry]) -> list[list[Entry]]:
        """Entries without a summary, in batches for the workers."""
        todo = [e for e in entries.values() if e.summary is None]
        return [todo[i:i + BATCH] for i in range(0, len(todo), BATCH)]


def regular_files(root: Path):
    """``(path, stat)`` of every ``*.replay.json`` regular file under ``root``, never following links."""
    if not root.is_dir():
        return
    for folder, dirs, files in os.walk(root, followlinks=False):
        dirs.sort()
        for name in sorted(files):
            if not name.endswith(SUFFIX):
                continue
            path = Path(folder) / name
            try:
                info = path.lstat()
            except OSError:
                continue
            if stat.S_ISREG(info.st_mode):
                yield path, info


def role_policies(replay, role: str) -> str | None:
    """The policy of the role's agent (1:1), or the role's distinct policies joined with "+" (``human+astar``)."""
    names = [name for name, r in zip(replay.config.agent_names, replay.config.roles) if r == role]
    policies = [replay.agents.get(name, {}).get("policy") for name in names]
    distinct = list(dict.fromkeys(str(p) for p in policies if p is not None))
    return "+".join(distinct) if distinct else None


BRANCH_SOURCE = "branch"
"""The list's ``source`` of a branch (its file keeps its parent's ``source``: see ``branch_origin``)."""


def branch_origin(replay) -> dict | None:
    """Where a branch leaves its parent (``meta.branch_of`` and ``meta.branch``, docs/REPLAY_FORMAT.md): ``parent``
    (the parent's replay id, or its file name for a branch made by ``colorgrid replay branch``), ``step`` (the first
    step the new follower acts in), the ``follower`` and ``leader`` that play on, and ``parent_source``; None for a
    replay that is not a branch."""
    origin, made = replay.meta.get("branch_of"), replay.meta.get("branch")
    if not isinstance(origin, dict):
        return None
    made = made if isinstance(made, dict) else {}
    return {"parent": origin.get("file"), "step": origin.get("step", made.get("step")),
            "follower": made.get("follower"), "leader": made.get("leader", "recorded"), "parent_source": replay.source}


def summarize(path: Path, replay_id: str, collection: str, max_bytes: int | None = None) -> dict:
    """What the list shows for one file; a file that does not load is listed with its error."""
    base = {"id": replay_id, "collection": collection, "file": path.name}
    try:
        replay = load(path, max_bytes=max_bytes)
    except ReplayError as err:
        return {**base, "error": err.problem}
    cfg = replay.config
    origin = branch_origin(replay)
    policies = {role: role_policies(replay, role) for role in ROLES}
    if origin is not None and origin["leader"] == "recorded":  # nobody played it: the parent's leader moves, replayed
        policies["leader"] = f"{policies['leader']} (replayed)"
    return {
        **base, "source": BRANCH_SOURCE if origin else replay.source, "branch_of": origin, "created": replay.created,
        "kind": replay.kind, "ended": replay.ended, "steps": replay.num_steps, **policies,
        "team": cfg.team,
        "final": replay.final(),
        "config": {"asymmetric": cfg.asymmetric, "goal_reward": cfg.goal_reward, "wrong_penalty": cfg.wrong_penalty,
                   "switch_prob": cfg.switch_prob, "horizon": cfg.horizon},
        "setting": replay.meta.get("setting") or replay.meta.get("preset"),
    }
