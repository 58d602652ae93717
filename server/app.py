"""The FastAPI application: pages, the replay API and the play WebSocket."""

from __future__ import annotations

import asyncio
import json
import tempfile
import time
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, HTTPException, Query, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from pydantic import ValidationError

from colorgrid import __version__
from colorgrid.cli_config import PRESETS
from server.hub import GameHub, ServerFull
from server.protocol import CLIENT_TYPES, Key, NewGame, Ping, Quit, Rejoin, client_message, error
from server.replays import ReplayCatalogue
from server.settings import REPO_ROOT, ServerSettings

WEB_DIR = REPO_ROOT / "web"
CLOSE_POLICY = 1008


def create_app(settings: ServerSettings | None = None) -> FastAPI:
    settings = settings or ServerSettings()
    hub = GameHub(settings)
    catalogue = ReplayCatalogue(settings.replays_dir, settings.released_dir)
    export_dir = Path(tempfile.mkdtemp(prefix="colorgrid-exports-"))

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        hub.start()
        yield
        await hub.stop()

    app = FastAPI(title="ColorGrid play server", version=__version__, lifespan=lifespan)
    app.state.hub, app.state.settings = hub, settings

    @app.get("/", include_in_schema=False)
    async def play_page():
        return FileResponse(WEB_DIR / "index.html")

    @app.get("/replays", include_in_schema=False)
    async def replays_page():
        return FileResponse(WEB_DIR / "replays.html")

    @app.get("/replay", include_in_schema=False)
    async def replay_page():
        return FileResponse(WEB_DIR / "replay.html")

    app.mount("/static", StaticFiles(directory=WEB_DIR), name="static")

    @app.get("/api/health")
    async def health():
        """Liveness and load: games running, the limit, tick statistics."""
        lateness = sorted(hub.lateness_ms)  # the last 5000 ticks

        def pct(q):
            return round(lateness[int(q * (len(lateness) - 1))], 2) if lateness else 0.0

        return {"status": "ok", "ready": hub.ready, "version": __version__, "games": len(hub.games), "max_sessions": settings.max_sessions,
                "tick_hz": settings.tick_hz, "tick_lateness_p50_ms": pct(0.5), "tick_lateness_p99_ms": pct(0.99),
                **hub.stats}

    @app.get("/api/options")
    async def options():
        """What a new game may choose: followers, presets, modes, and the defaults."""
        return {"followers": list(settings.followers), "default_follower": settings.follower,
                "presets": sorted(PRESETS), "default_preset": settings.preset, "modes": ["turn", "realtime"],
                "tick_hz": settings.tick_hz, "show_belief": settings.show_belief}

    @app.get("/api/replays")
    async def list_replays(source: str | None = None, follower: str | None = None, collection: str | None = None,
                           setting: str | None = None,
                           sort: str = Query("created", pattern="^(created|team_score)$"),
                           order: str = Query("desc", pattern="^(asc|desc)$"),
                           offset: int = Query(0, ge=0), limit: int = Query(50, ge=1, le=500)):
        """Recorded and released replays, filtered, sorted and paginated."""
        items = [e.summary for e in catalogue.entries().values()]
        if source:
            items = [i for i in items if i.get("source") == source]
        if follower:
            items = [i for i in items if i.get("follower") == follower]
        if collection:
            items = [i for i in items if i.get("collection") == collection]
        if setting:
            items = [i for i in items if i.get("setting") == setting
                     or (setting in ("asymmetric", "symmetric") and "config" in i
                         and i["config"]["asymmetric"] == (setting == "asymmetric"))]

        def key(i):
            return (i.get("final", {}).get("team_score", float("-inf")) if sort == "team_score"
                    else i.get("created", ""))

        items.sort(key=key, reverse=order == "desc")
        return {"total": len(items), "offset": offset, "limit": limit, "items": items[offset:offset + limit]}

    @app.get("/api/replays/{replay_id}")
    async def get_replay(replay_id: str):
        """One replay file, as stored."""
        entry = catalogue.get(replay_id)
        if entry is None:
            raise HTTPException(404, f"no replay with id {replay_id!r}")
        return JSONResponse(json.loads(entry.path.read_text()))

    @app.get("/api/replays/{replay_id}/timeline")
    async def replay_timeline(replay_id: str):
        """What the replay player draws: verification, one board per step, belief curves, events, key log."""
        from colorgrid.replay import ReplayError, load
        from colorgrid.replay.timeline import timeline

        entry = catalogue.get(replay_id)
        if entry is None:
            raise HTTPException(404, f"no replay with id {replay_id!r}")
        try:
            replay = load(entry.path)
        except ReplayError as err:
            return {"id": replay_id, "verified": False, "problem": err.problem}
        try:
            data = await asyncio.get_running_loop().run_in_executor(None, timeline, replay, entry.path)
        except ReplayError as err:
            return {"id": replay_id, "verified": False, "problem": err.problem}
        return {"id": replay_id, **data}

    @app.get("/api/replays/{replay_id}/export")
    async def export_replay(replay_id: str, format: str = Query("gif", pattern="^(gif|mp4)$")):
        """The replay as a GIF or MP4, made on the server (cached)."""
        from colorgrid.export import export
        from colorgrid.replay import ReplayError, load

        entry = catalogue.get(replay_id)
        if entry is None:
            raise HTTPException(404, f"no replay with id {replay_id!r}")
        out = export_dir / f"{replay_id}-{int(entry.mtime)}.{format}"
        if not out.exists():
            try:
                replay = load(entry.path)
                await asyncio.get_running_loop().run_in_executor(None, export, replay, out, format)
            except ReplayError as err:
                raise HTTPException(422, f"replay cannot be exported: {err.problem}") from None
        media = "image/gif" if format == "gif" else "video/mp4"
        return FileResponse(out, media_type=media, filename=f"{replay_id}.{format}")

    @app.websocket("/ws/play")
    async def play_socket(ws: WebSocket):
        await ws.accept()
        conn = Connection(ws, settings)
        writer = asyncio.create_task(conn.writer())
        try:
            await conn.serve(hub)
        except WebSocketDisconnect:
            pass
        finally:
            conn.closed = True
            writer.cancel()
            if conn.game is not None:
                hub.disconnect(conn.game)

    return app


class Connection:
    """One browser tab's WebSocket: validation, rate limits, and an outgoing queue per socket."""

    def __init__(self, ws: WebSocket, settings: ServerSettings):
        self.ws, self.settings = ws, settings
        self.game = None
        self.closed = False
        self.outbox: asyncio.Queue = asyncio.Queue(maxsize=256)
        self.tokens = 2 * settings.max_messages_per_s
        self.refill_at = time.monotonic()
        self.refused = 0
        self.last_refusal_notice = 0.0

    async def send(self, message: dict) -> None:
        if self.closed:
            raise ConnectionError("socket closed")
        if self.outbox.full():  # a slow reader: drop the oldest queued message, keep the newest state
            self.outbox.get_nowait()
        self.outbox.put_nowait(message)

    async def writer(self) -> None:
        while True:
            message = await self.outbox.get()
            await self.ws.send_text(json.dumps(message))

    def allow(self) -> bool:
        """Token bucket: ``max_messages_per_s`` sustained, bursts of twice that."""
        now = time.monotonic()
        rate = self.settings.max_messages_per_s
        self.tokens = min(2 * rate, self.tokens + (now - self.refill_at) * rate)
        self.refill_at = now
        if self.tokens >= 1:
            self.tokens -= 1
            self.refused = 0
            return True
        return False

    async def serve(self, hub: GameHub) -> None:
        while True:
            raw = await self.ws.receive()
            if raw["type"] == "websocket.disconnect":
                raise WebSocketDisconnect(raw.get("code", 1000))
            text = raw.get("text")
            size = len(text.encode()) if text is not None else len(raw.get("bytes") or b"")
            if not self.allow():
                self.refused += 1
                if self.refused > 20 * self.settings.max_messages_per_s:
                    await self.ws.close(CLOSE_POLICY, "message flood")
                    raise WebSocketDisconnect(CLOSE_POLICY)
                if time.monotonic() - self.last_refusal_notice > 1.0:
                    self.last_refusal_notice = time.monotonic()
                    await self.send(error("rate_limited", f"too many messages: at most "
                                                          f"{self.settings.max_messages_per_s:g}/s; extra ones are refused"))
                continue
            if size > self.settings.max_message_bytes:
                await self.send(error("too_large", f"message of {size} bytes refused; the limit is "
                                                   f"{self.settings.max_message_bytes}"))
                continue
            if text is None:
                await self.send(error("bad_json", "binary messages are not supported; send JSON text"))
                continue
            await self.handle(hub, text)

    async def handle(self, hub: GameHub, text: str) -> None:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            await self.send(error("bad_json", f"not valid JSON: {err.msg} at position {err.pos}"))
            return
        if not isinstance(data, dict) or data.get("type") not in CLIENT_TYPES:
            kind = data.get("type") if isinstance(data, dict) else None
            await self.send(error("unknown_type", f"unknown message type {kind!r}; expected one of {list(CLIENT_TYPES)}"))
            return
        try:
            msg = client_message.validate_python(data)
        except ValidationError as err:
            first = err.errors()[0]
            where = ".".join(str(p) for p in first["loc"][1:]) or "message"
            await self.send(error("invalid_message", f"{data['type']}: {where}: {first['msg']}"))
            return
        try:
            await self.dispatch(hub, msg)
        except ServerFull as err:
            await self.send({"type": "full", "message": str(err)})
        except ValueError as err:
            await self.send(error("rejected", str(err)))

    async def dispatch(self, hub: GameHub, msg) -> None:
        if isinstance(msg, Ping):
            await self.send({"type": "pong", "t_server": time.time() * 1000})
        elif isinstance(msg, (NewGame, Rejoin)):
            if self.game is not None and self.game.game_id in hub.games:
                raise ValueError("this connection already has a live game; send quit first")
            if isinstance(msg, NewGame):
                self.game = await hub.new_game(msg.follower, msg.preset, msg.mode, msg.horizon, msg.show_belief,
                                               self.send)
            else:
                self.game = await hub.rejoin(msg.game_id, msg.token, self.send)
        elif self.game is None or self.game.game_id not in hub.games:
            raise ValueError("no live game on this connection: send new_game or rejoin first")
        elif isinstance(msg, Key):
            problem = await hub.key(self.game, msg.key, msg.seq, msg.t_client)
            if problem:
                await self.send(error("bad_key", problem))
        elif isinstance(msg, Quit):
            await hub.finish(self.game, "quit")
