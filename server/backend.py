"""What one play-server process owns (``Backend``) and what several processes share (``Shared``).

A deployment may run several play-server processes behind one proxy: they write their games into one
recordings folder and, during a study, one study store. Everything else lives and dies with its
process: the games and rooms it runs, their tick loops, its inference process, its play sockets, its
replay worker processes and what it has cached of the shared folder. Routes reach all of it through
``request.app.state.backend`` (the ``CurrentBackend`` dependency), never through module globals.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Protocol

from fastapi import Depends, FastAPI
from starlette.requests import HTTPConnection

from server.connection import CLOSE_RESTART, SocketRegistry
from server.jobs import ReplayJobs
from server.library import ReplayLibrary
from server.play.hub import GameHub
from server.settings import ServerSettings

if TYPE_CHECKING:  # a cluster's membership is known only where several processes run
    from server.cluster.plan import Membership


class Plugin(Protocol):
    """An application the play server serves instead of free play (a study: ``colorgrid study run``). It is
    picklable: a cluster's launcher hands it to every backend process, and each installs it in its own app."""

    routing_params: tuple[str, ...]
    """The URL parameters that name a person (a participant id): behind HAProxy, a browser's requests go to the
    backend this value hashes to."""

    def install(self, app: FastAPI, backend: Backend) -> None:
        """Add its routes and pages to ``app``, and plug into ``backend``: its game source (``hub.source``) and
        listeners (``hub.listeners``); what it opens it closes through ``backend.closing``."""


@dataclass(frozen=True)
class Shared:
    """What every process of one deployment reads and writes alike; no process owns it."""

    settings: ServerSettings
    """How every process runs (``colorgrid play``'s flags)."""
    plugin: Plugin | None = None
    """The application served (a study: its file, store and admin token), or None for free play."""

    @property
    def recordings(self) -> Path:
        """The recordings folder: every process saves its games' replays (and branches) here and lists them."""
        return self.settings.replays_dir


class Backend:
    """One play-server process: the shared parts and what it owns.

    ``hub`` holds its games and waiting rooms, their tick loops and its inference process;
    ``sockets`` its open play sockets and their rate limits; ``jobs`` its replay worker processes
    and export cache; ``replays`` what it has scanned of the shared replay folders; ``member`` its place among
    several processes behind HAProxy (``server.cluster``), None when it runs alone.
    """

    def __init__(self, shared: Shared):
        settings = shared.settings
        self.shared = shared
        self.hub = GameHub(settings)
        self.sockets = SocketRegistry(settings)
        self.jobs = ReplayJobs(settings.max_exports, int(settings.export_cache_mb * 1e6))
        self.replays = ReplayLibrary(settings, self.jobs)
        self.member: Membership | None = None  # set by server.cluster.siblings.join_cluster
        self.closing: list[Callable[[], None]] = []  # what a plugin opened in this process, closed at the end
        self._warm_up: asyncio.Task | None = None

    @property
    def settings(self) -> ServerSettings:
        return self.shared.settings

    def start(self) -> None:
        """Start the tick loops, the sweeper and the followers' warm-up, and the replay workers (in the event loop)."""
        self.hub.start()
        self._warm_up = asyncio.create_task(self.jobs.warm_up())

    async def shutdown(self) -> None:
        """Save every live game, tell each player (``game_over``, reason ``server_shutdown``) and then close its
        socket. Runs before the web server closes connections; calling it again does nothing."""
        told = await self.hub.stop()
        await asyncio.gather(*(conn.close_after_sending(CLOSE_RESTART, "server shutdown") for conn in told),
                             return_exceptions=True)

    async def stop(self) -> None:
        """``shutdown``, then stop the replay workers, remove the export cache and close what a plugin opened."""
        if self._warm_up is not None:
            self._warm_up.cancel()
        await self.shutdown()
        self.jobs.close()
        for close in self.closing:
            close()


def current_backend(conn: HTTPConnection) -> Backend:
    """The backend of the process serving this request or socket."""
    return conn.app.state.backend


CurrentBackend = Annotated[Backend, Depends(current_backend)]
"""A route's parameter type for this process's backend (a FastAPI dependency)."""
