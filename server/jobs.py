"""Replay work off the event loop: loading, verifying and exporting run in low-priority worker processes.

Parsing a large JSON file or drawing a video holds Python's GIL for seconds; in a thread of
the server's own process that would stall the real-time tick and the follower's inference.
Worker processes (``nice`` 10, so the server's own threads win the CPU) do it instead, and
hand back small results: a summary, a problem, JSON bytes, or a file written to the cache.
"""

from __future__ import annotations

import asyncio
import json
import logging
import multiprocessing
import os
import shutil
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

log = logging.getLogger("colorgrid.server")
CACHE_PREFIX = "colorgrid-exports-"


class Busy(Exception):
    """Too much replay work is already running; the client should retry later."""

    def __init__(self, what: str, retry_after_s: int = 5):
        super().__init__(f"the server is busy with {what}; retry in {retry_after_s} s")
        self.retry_after_s = retry_after_s


# ---------------------------------------------------------------- in the worker processes
def _lower_priority() -> None:
    """Each worker's set-up: a lower CPU priority, Ctrl+C left to the server (which stops the workers), and an
    end of its own if the server is killed (its task queue would never close: the worker would wait for ever)."""
    import signal
    import threading

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        os.nice(10)
    except OSError:  # not allowed here: run at normal priority
        pass
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), daemon=True, name="parent-watch").start()


def _exit_with_parent(parent: int, every_s: float = 1.0) -> None:
    """End this process once ``parent`` is gone (this process is handed to another parent then)."""
    while os.getppid() == parent:
        time.sleep(every_s)
    os._exit(0)


def summaries(files: list[tuple[str, str, str]], max_bytes: int) -> list[dict]:
    """``summarize`` for each ``(path, replay_id, collection)``."""
    from server.replays import summarize

    out = []
    for p, replay_id, collection in files:
        try:
            out.append(summarize(Path(p), replay_id, collection, max_bytes))
        except Exception as err:  # a file no check foresaw: listed as broken, the rest still summarised
            out.append({"id": replay_id, "collection": collection, "file": Path(p).name,
                        "error": f"cannot be read: {type(err).__name__}"})
    return out


def timeline_file(path: str, replay_id: str, out: str, max_bytes: int) -> None:
    """Write what the replay player draws as JSON to ``out`` (``verified: false`` with the problem if the
    replay does not load). A file, not a return value: a large timeline then never passes through the
    server's own process in one piece; the server streams it."""
    from colorgrid.files import atomic_path
    from colorgrid.replay import ReplayError, load
    from colorgrid.replay.timeline import timeline

    try:
        replay = load(path, max_bytes=max_bytes)
        data = {"id": replay_id, **timeline(replay, path)}
    except ReplayError as err:
        data = {"id": replay_id, "verified": False, "problem": err.problem}
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps(data, separators=(",", ":"), allow_nan=False))


def export_file(path: str, out: str, fmt: str, max_bytes: int) -> str | None:
    """Export the replay at ``path`` to ``out``; returns the problem if it cannot be exported."""
    from colorgrid.replay import ReplayError, load
    from colorgrid.replay.export import export

    try:
        export(load(path, max_bytes=max_bytes), out, fmt, path=path)
    except ReplayError as err:
        return err.problem
    return None


def branch_file(path: str, out: str, step: int, follower: str, parent_id: str, max_bytes: int) -> str | None:
    """Save the replay at ``path`` continued from ``step`` with ``follower`` (``colorgrid.replay.branch``: the
    leader replays its recorded moves) to ``out``; returns the problem if it cannot be branched. A branch that
    exists already is kept (the same parent, step, follower and seed give the same game)."""
    from colorgrid.replay import ReplayError, load, save
    from colorgrid.replay.branch import branch

    if Path(out).exists():
        return None
    try:
        save(branch(load(path, max_bytes=max_bytes), step, follower, parent_name=parent_id), out)
    except (ReplayError, ValueError) as err:  # a file that does not load or is not an actions replay; a bad step
        return getattr(err, "problem", None) or str(err)
    except OSError as err:  # a follower's checkpoint gone, a full disk
        return f"cannot be written or read: {err.strerror or err}"
    return None


def people_file(path: str, follower: str, out: str, max_bytes: int) -> str | None:
    """Write each person in a follower seat of the replay at ``path`` beside ``follower`` watching their seat
    (``colorgrid.replay.human_follower.person_and_follower``) as JSON to ``out``; returns the problem if there is
    nothing to write (a file that does not load, a game without a person in a follower seat)."""
    from colorgrid.files import atomic_path
    from colorgrid.replay import ReplayError, load
    from colorgrid.replay.human_follower import person_and_follower

    try:
        seats = person_and_follower(load(path, max_bytes=max_bytes), follower)
    except (ReplayError, ValueError) as err:  # a file that does not load, a frames replay
        return getattr(err, "problem", None) or str(err)
    except OSError as err:  # a follower's checkpoint gone
        return f"cannot be read: {err.strerror or err}"
    if not seats:
        return "no person played a follower seat in this game (their stated beliefs are what it measures)"
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps({"follower": follower, "seats": seats}, separators=(",", ":"), allow_nan=False))
    return None


def _ready() -> bool:
    return True


# ---------------------------------------------------------------- in the server
class ReplayJobs:
    """A small pool of worker processes, a cap on concurrent exports, and a bounded export cache."""

    def __init__(self, max_exports: int, cache_bytes: int, workers: int | None = None, max_queued: int = 32):
        # One worker on a machine of two cores or fewer: the other core stays for the tick and the follower.
        workers = workers or (1 if (os.cpu_count() or 1) <= 2 else 2)
        self.pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                        initializer=_lower_priority)
        self.workers, self.max_exports, self.cache_bytes, self.max_queued = workers, max_exports, cache_bytes, max_queued
        self.exporting = 0
        self.queued = 0
        remove_stale_caches()
        self.cache_dir = Path(tempfile.mkdtemp(prefix=f"{CACHE_PREFIX}{os.getpid()}-"))
        self._making: dict[Path, asyncio.Future] = {}

    async def run(self, fn, *args):
        """``fn(*args)`` in a worker process; ``Busy`` when too much is queued already."""
        if self.queued >= self.max_queued:
            raise Busy("replay requests")
        self.queued += 1
        try:
            return await asyncio.wrap_future(self.pool.submit(fn, *args))
        finally:
            self.queued -= 1

    async def warm_up(self) -> None:
        """Start the workers before anyone waits on them."""
        await asyncio.gather(*(self.run(_ready) for _ in range(self.workers)))

    async def export(self, path: Path, replay_id: str, mtime: float, fmt: str, max_bytes: int) -> Path:
        """The exported file, from the cache or made now; ``ValueError`` with the problem; ``Busy`` past the cap."""
        out = self.cache_dir / f"{replay_id}-{mtime:.6f}.{fmt}"
        if out.exists() or out in self._making:
            return await self._cached(out, None)
        if self.exporting >= self.max_exports:
            raise Busy(f"{self.exporting} exports", retry_after_s=10)
        self.exporting += 1
        return await self._cached(out, lambda: self.run(export_file, str(path), str(out), fmt, max_bytes), export=True)

    async def timeline(self, path: Path, replay_id: str, mtime: float, max_bytes: int) -> Path:
        """The timeline's JSON file, from the cache or made now."""
        out = self.cache_dir / f"{replay_id}-{mtime:.6f}.timeline.json"
        return await self._cached(out, lambda: self.run(timeline_file, str(path), replay_id, str(out), max_bytes))

    async def people(self, path: Path, replay_id: str, mtime: float, follower: str, follower_part: str,
                     max_bytes: int) -> Path:
        """The person-and-AI JSON file of a follower-seat replay beside ``follower`` (``people_file``), from the cache
        or made now; ``ValueError`` with the problem. ``follower_part``: the follower's name as part of a file name."""
        out = self.cache_dir / f"{replay_id}-{mtime:.6f}.people-{follower_part}.json"
        return await self._cached(out, lambda: self.run(people_file, str(path), follower, str(out), max_bytes))

    async def once(self, out: Path, make, done=None):
        """What ``make()`` returns, the job that writes ``out``: at most one job per file, however many requests
        wait for it; ``done()`` is called once the job has ended."""
        running = self._making.get(out)
        if running is None:
            running = asyncio.ensure_future(make())
            self._making[out] = running
            running.add_done_callback(lambda _: self._making.pop(out, None))
            if done is not None:
                running.add_done_callback(lambda _: done())
        return await asyncio.shield(running)

    async def _cached(self, out: Path, make, export: bool = False) -> Path:
        """``out`` once made: at most one job per file, however many requests wait for it."""
        if out.exists() and out not in self._making:
            os.utime(out)  # recently used: evicted last
            return out
        problem = await self.once(out, make, lambda: self._done(export))
        if problem is not None:
            raise ValueError(problem)
        return out

    def _done(self, export: bool) -> None:
        self.exporting -= export
        try:
            self.trim_cache()
        except OSError:
            log.exception("could not trim the export cache")

    def trim_cache(self) -> None:
        """Remove the least recently used exports until the cache fits its budget."""
        files = [(p.stat().st_mtime, p.stat().st_size, p) for p in self.cache_dir.iterdir() if p.is_file()]
        total = sum(size for _, size, _ in files)
        for _, size, path in sorted(files):
            if total <= self.cache_bytes:
                break
            if path not in self._making:
                path.unlink(missing_ok=True)
                total -= size

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)  # a running job finishes (seconds at most)
        shutil.rmtree(self.cache_dir, ignore_errors=True)


def remove_stale_caches() -> None:
    """Export caches left by server processes that no longer run (killed before they could clean up)."""
    for folder in Path(tempfile.gettempdir()).glob(f"{CACHE_PREFIX}*"):
        pid = folder.name[len(CACHE_PREFIX):].split("-", 1)[0]
        if pid.isdigit() and not _alive(int(pid)) and time.time() - folder.stat().st_mtime > 60:
            shutil.rmtree(folder, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
