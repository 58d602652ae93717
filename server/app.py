"""The FastAPI application: this process's ``Backend`` over the ``Shared`` parts, and the routers
(``server.routes``: pages, replays, play, health; ``server.study.routes`` while a study runs)."""

from __future__ import annotations

from contextlib import asynccontextmanager

from fastapi import FastAPI
from starlette.middleware.trustedhost import TrustedHostMiddleware

from colorgrid import __version__
from server.backend import Backend, Shared
from server.followers import follower_info
from server.jobs import Busy
from server.routes import health, pages, play, replays
from server.routes.replays import file_part
from server.settings import ServerSettings

__all__ = ["create_app", "file_part", "follower_info", "shutdown"]


def create_app(settings: ServerSettings | None = None, study=None) -> FastAPI:
    """The play server; with ``study`` (a ``server.study.cli.StudySetup``) it serves that study instead of free play."""
    shared = Shared.open(settings or ServerSettings(), study)
    backend = Backend(shared)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        backend.start()
        try:
            yield
        finally:
            await backend.stop()
            shared.close()

    # The documentation pages are served with local assets (FastAPI's defaults load them from a CDN).
    app = FastAPI(title="ColorGrid play server", version=__version__, lifespan=lifespan,
                  docs_url=None, redoc_url=None)
    app.state.backend = backend
    if study is not None:
        from server.study.routes import mount_study

        mount_study(app, shared.service, study.admin_token, pages.WEB_DIR, backend.jobs, study.study_file,
                    shared.recordings, backend.study_games)
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
