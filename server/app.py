"""The FastAPI application: this process's ``Backend`` over the ``Shared`` parts, and the routers
(``server.routes``: pages, replays, play, health), plus what a plugin installs (a study's routes and game source)."""

from __future__ import annotations

from contextlib import asynccontextmanager

from fastapi import FastAPI
from starlette.middleware.trustedhost import TrustedHostMiddleware

from colorgrid import __version__
from server.backend import Backend, Plugin, Shared
from server.followers import follower_info
from server.jobs import Busy
from server.routes import health, pages, play, replays
from server.routes.replays import file_part
from server.settings import ServerSettings

__all__ = ["create_app", "file_part", "follower_info", "shutdown"]


def create_app(settings: ServerSettings | None = None, plugin: Plugin | None = None) -> FastAPI:
    """The play server; with ``plugin`` (a study's) it serves that application instead of free play."""
    shared = Shared(settings or ServerSettings(), plugin)
    backend = Backend(shared)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        backend.start()
        try:
            yield
        finally:
            await backend.stop()

    # The documentation pages are served with local assets (FastAPI's defaults load them from a CDN).
    app = FastAPI(title="ColorGrid play server", version=__version__, lifespan=lifespan,
                  docs_url=None, redoc_url=None)
    app.state.backend = backend
    if plugin is not None:
        plugin.install(app, backend)
    # Requests naming another host are refused (a page on another site cannot reach us by DNS rebinding).
    app.add_middleware(TrustedHostMiddleware, allowed_hosts=shared.settings.hosts, www_redirect=False)
    for module in (pages, health, play, replays):
        app.include_router(module.router)
    app.add_exception_handler(Busy, replays.busy)
    return app


async def shutdown(app: FastAPI) -> None:
    """Save every live game, tell each player (``game_over``, reason ``server_shutdown``) and then
    close its socket. Runs before the web server closes connections; calling it again does nothing."""
    await app.state.backend.shutdown()
