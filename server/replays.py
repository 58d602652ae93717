"""The replay catalogue served under /api/replays: ids only, never paths from the request."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from colorgrid.replay import ReplayError, load

ID_PATTERN = re.compile(r"^[A-Za-z0-9_.+-]{1,200}$")


@dataclass
class Entry:
    id: str
    path: Path
    collection: str  # "recorded" or "released"
    mtime: float
    summary: dict


class ReplayCatalogue:
    """Scans the recordings folder and the released set; caches each file's summary by mtime."""

    def __init__(self, recorded_dir: Path, released_dir: Path | None):
        self.roots = [("recorded", Path(recorded_dir))]
        if released_dir is not None:
            self.roots.append(("released", Path(released_dir)))
        self.cache: dict[Path, Entry] = {}

    def entries(self) -> dict[str, Entry]:
        out: dict[str, Entry] = {}
        for collection, root in self.roots:
            if not root.is_dir():
                continue
            for path in root.rglob("*.replay.json"):
                rel = path.relative_to(root).as_posix()[: -len(".replay.json")]
                replay_id = (("released--" if collection == "released" else "") + rel.replace("/", "--"))
                if not ID_PATTERN.match(replay_id):
                    continue
                mtime = path.stat().st_mtime
                cached = self.cache.get(path)
                if cached is None or cached.mtime != mtime:
                    cached = Entry(replay_id, path, collection, mtime, summarize(path, replay_id, collection))
                    self.cache[path] = cached
                out[replay_id] = cached
        return out

    def get(self, replay_id: str) -> Entry | None:
        if not ID_PATTERN.match(replay_id):
            return None
        return self.entries().get(replay_id)


def summarize(path: Path, replay_id: str, collection: str) -> dict:
    """What the list shows for one file; a file that does not load is listed with its error."""
    base = {"id": replay_id, "collection": collection, "file": path.name}
    try:
        replay = load(path)
    except ReplayError as err:
        return {**base, "error": err.problem}
    cfg = replay.config
    return {
        **base, "source": replay.source, "created": replay.created, "kind": replay.kind, "ended": replay.ended,
        "steps": replay.num_steps, "leader": replay.agents.get("leader", {}).get("policy"),
        "follower": replay.agents.get("follower", {}).get("policy"), "final": replay.final(),
        "config": {"asymmetric": cfg.asymmetric, "goal_reward": cfg.goal_reward, "wrong_penalty": cfg.wrong_penalty,
                   "switch_prob": cfg.switch_prob, "horizon": cfg.horizon},
        "setting": replay.meta.get("setting") or replay.meta.get("preset"),
    }
