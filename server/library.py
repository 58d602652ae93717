"""One process's view of the replay folders: the recorded games (shared by every process) and the released set.

The folders are scanned on a thread and each new file version summarised in the replay worker
processes (``server.jobs``); requests arriving together share one scan, and a scan under a second
old is reused. Branches are made in the workers too, once per file however many ask for it.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

from server.jobs import ReplayJobs, branch_file, summaries
from server.limits import AddressLimits
from server.replays import ID_PATTERN, SUFFIX, Entry, ReplayCatalogue
from server.settings import ServerSettings

BRANCHES_PER_MINUTE = 30
"""Branches one client address may ask for a minute."""
MAX_BRANCHES = 2000
"""Branch files the server keeps in ``recordings/branches/``; past it, new branches are refused (503)."""
SCAN_REUSE_S = 1.0
"""How old a finished scan may be and still answer a request."""


class ReplayLibrary:
    """The replays this process lists, serves and branches; ``jobs`` does the reading."""

    def __init__(self, settings: ServerSettings, jobs: ReplayJobs):
        self.catalogue = ReplayCatalogue(settings.replays_dir, settings.released_dir)
        self.branches_dir = settings.replays_dir / "branches"
        self.jobs = jobs
        self.max_bytes = int(settings.max_replay_mb * 1e6)
        self.branch_limits = AddressLimits(BRANCHES_PER_MINUTE / 60.0, burst=BRANCHES_PER_MINUTE)
        self._scan: asyncio.Future | None = None
        self._scanned_at = -1.0

    async def entries(self) -> dict[str, Entry]:
        """Every replay by id, each with its summary (a broken file's summary holds its ``error``)."""
        if self._scan is None or (self._scan.done() and time.monotonic() - self._scanned_at > SCAN_REUSE_S):
            self._scanned_at, self._scan = time.monotonic(), asyncio.ensure_future(self._scan_now())
        return await asyncio.shield(self._scan)

    async def find(self, replay_id: str) -> Entry | None:
        """The replay with this id, or None (an id that is not well formed is never looked up)."""
        return (await self.entries()).get(replay_id) if ID_PATTERN.match(replay_id) else None

    async def _scan_now(self) -> dict[str, Entry]:
        found = await asyncio.to_thread(self.catalogue.scan)
        for batch in self.catalogue.missing(found):
            done = await self.jobs.run(summaries, [(str(e.path), e.id, e.collection) for e in batch], self.max_bytes)
            for entry, summary in zip(batch, done):
                entry.summary = summary
        return found

    def branch_path(self, name: str) -> Path:
        """Where the branch called ``name`` is saved (its id is ``branches--<name>``)."""
        return self.branches_dir / f"{name}{SUFFIX}"

    def branches_full(self) -> bool:
        """Whether ``MAX_BRANCHES`` branch files are kept already."""
        return sum(1 for _ in self.branches_dir.glob(f"*{SUFFIX}")) >= MAX_BRANCHES

    async def branch(self, entry: Entry, out: Path, step: int, follower: str) -> str | None:
        """Save ``entry`` continued from ``step`` with ``follower`` to ``out`` (one job per file, however many
        requests ask for it); the problem if it cannot be branched. The next listing shows the new file."""
        problem = await self.jobs.once(out, lambda: self.jobs.run(branch_file, str(entry.path), str(out), step,
                                                                  follower, entry.id, self.max_bytes))
        if problem is None:
            self._scan = None
        return problem
