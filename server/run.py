"""Running the play server: uvicorn with a graceful shutdown that saves games first, and slow-client timeouts."""

from __future__ import annotations

import asyncio
import copy
import logging

import uvicorn
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from server.app import create_app, shutdown
from server.settings import ServerSettings


class HeaderTimeoutProtocol(HttpToolsProtocol):
    """HTTP/1.1 that closes a connection whose request headers are not complete in time.

    uvicorn bounds idle keep-alive connections, but not a request that arrives a byte at a
    time ("slowloris"): each such connection would stay open for ever.
    """

    header_timeout_s = 10.0

    def connection_made(self, transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm()

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._arm()

    def on_headers_complete(self) -> None:
        self._disarm()
        super().on_headers_complete()

    def connection_lost(self, exc) -> None:
        self._disarm()
        super().connection_lost(exc)

    def _arm(self) -> None:
        self._disarm()
        self._header_timer = self.loop.call_later(self.header_timeout_s, self._headers_too_slow)

    def _disarm(self) -> None:
        timer = getattr(self, "_header_timer", None)
        if timer is not None:
            timer.cancel()
            self._header_timer = None

    def _headers_too_slow(self) -> None:
        self._header_timer = None
        if not self.transport.is_closing():
            self.transport.close()


class PlayServer(uvicorn.Server):
    """On SIGTERM/Ctrl+C: stop accepting, save every live game and send each player its ``game_over``
    (with the replay id), close those sockets, and only then let uvicorn close the rest."""

    def __init__(self, config: uvicorn.Config, app):
        super().__init__(config)
        self.play_app = app

    async def shutdown(self, sockets=None) -> None:
        for server in self.servers:
            server.close()
        try:
            await asyncio.wait_for(shutdown(self.play_app), 30)
        except Exception:  # never skip uvicorn's own shutdown
            logging.getLogger("colorgrid.server").exception("saving games at shutdown failed")
        await super().shutdown(sockets)


def serve(settings: ServerSettings, log_level: str = "info", plugin=None, member=None, announce=None) -> None:
    """Run the play server until interrupted (serving ``plugin``, the application served (a study), when given; as
    one backend of a cluster behind HAProxy with ``member``, a ``server.cluster.plan.Membership``).
    ``announce(url)``, when given, is called with the address it listens on once the port is bound (``--port 0``
    picks a free one: the address names the port it got)."""
    app = create_app(settings, plugin)
    log_config = uvicorn.config.LOGGING_CONFIG
    if member is not None:
        from server.cluster.siblings import join_cluster

        join_cluster(app, member)
        log_config = named_logs(member.name or f"{settings.host}:{settings.port}")
    protocol = type("Protocol", (HeaderTimeoutProtocol,), {"header_timeout_s": settings.header_timeout_s})
    # No per-message compression: deflating every state message for every player cost the event loop more
    # than any other part of a tick (a state is about 1.3 KB, 5 a second: bandwidth is not the limit).
    config = uvicorn.Config(app, host=settings.host, port=settings.port, log_level=log_level, ws_max_size=65536,
                            ws_per_message_deflate=False, http=protocol, timeout_graceful_shutdown=10,
                            log_config=log_config)
    sockets = None
    if settings.port == 0:  # bound here, so that the address announced is the one a free port gave
        sockets = [config.bind_socket()]
    if announce is not None:
        announce(f"http://{settings.host}:{sockets[0].getsockname()[1] if sockets else settings.port}")
    try:
        PlayServer(config, app).run(sockets=sockets)
    except KeyboardInterrupt:  # Ctrl+C: uvicorn has already shut down (games saved); no traceback for that
        pass


def named_logs(name: str) -> dict:
    """uvicorn's logging with each line marked by the backend it comes from (``[b2]``), without the lines a
    researcher reading the launcher's output does not need (``BackendLogs``)."""
    from server.cluster.haproxy import HEALTH_CHECK

    config = copy.deepcopy(uvicorn.config.LOGGING_CONFIG)
    for formatter in config["formatters"].values():
        formatter["fmt"] = formatter["fmt"].replace("%(levelprefix)s", f"%(levelprefix)s [{name}]", 1)
    config["filters"] = {"backend": {"()": BackendLogs, "health_check": HEALTH_CHECK}}
    for handler in config["handlers"].values():
        handler["filters"] = ["backend"]
    return config


class BackendLogs(logging.Filter):
    """A backend's log behind the launcher: its requests, warnings and errors, but not HAProxy's health check
    (every second: most of the log otherwise), nor uvicorn's own start and stop lines or its socket open and
    close lines (the launcher says when each backend is ready, stopped or started again)."""

    def __init__(self, health_check: str):
        super().__init__()
        self.health_check = health_check

    def filter(self, record: logging.LogRecord) -> bool:
        if record.name == "uvicorn.access":  # args: client, method, path with query, HTTP version, status
            return not (isinstance(record.args, tuple) and len(record.args) > 2 and record.args[2] == self.health_check)
        if record.name == "uvicorn.error" and record.levelno == logging.INFO:
            return '"WebSocket ' in str(record.msg)  # a socket's request line, as the access log has each request's
        return True
