"""The FastAPI application: pages, the replay API and the play WebSocket."""

from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import re
import time
from contextlib import asynccontextmanager
from pathlib import Path
from urllib.parse import urlsplit

import fastapi_offline
from fastapi import FastAPI, HTTPException, Query, Request, WebSocket, WebSocketDisconnect
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field, ValidationError
from starlette.middleware.trustedhost import TrustedHostMiddleware

from colorgrid import __version__
from colorgrid.presets import PRESETS, env_config
from colorgrid.render import look
from colorgrid.resources import shipped
from server.hub import GameHub, ServerFull
from server.jobs import Busy, ReplayJobs, branch_file, summaries
from server.limits import AddressLimits, FloodRule, TokenBucket
from server.protocol import (CLIENT_TYPES, KEY_ACTIONS, MAX_HORIZON, ROOM_CODE_LENGTH, CreateRoom, JoinRoom, Key, Mode,
                             NewGame, PageEvent, Ping, Quit, Ready, Rejoin, Team, client_message, error)
from server.replays import ID_PATTERN, SUFFIX, ReplayCatalogue
from server.rooms import RoomError
from server.settings import ServerSettings

WEB_DIR = shipped("web")
DOCS_ASSETS = Path(fastapi_offline.__file__).parent / "static"  # Swagger UI 5 and ReDoc, so /docs works offline
REDOC_LOGO = "https://cdn.redoc.ly/redoc/logo-mini.svg"  # ReDoc's footer fetches it; /redoc serves its own copy
EMPTY_SVG = "data:image/svg+xml,%3Csvg xmlns=%27http://www.w3.org/2000/svg%27/%3E"
CLOSE_POLICY = 1008  # a flood, or a page from an origin that is not allowed
CLOSE_GOING_AWAY = 1001  # idle without a game
CLOSE_RESTART = 1012  # the server is stopping (after game_over)
CLOSE_TRY_LATER = 1013  # too many connections
FLOOD_WINDOW_S = 5.0
log = logging.getLogger("colorgrid.server")


class BranchRequest(BaseModel):
    """``POST /api/replays/{id}/branch``: where to branch and which follower plays on."""

    step: int = Field(ge=0, le=MAX_HORIZON, description="the step the follower takes over at (0..the replay's steps)")
    follower: str = Field(max_length=200, description="one of /api/options' followers")


FOLLOWER_INFO = {
    "ippo": ("Trained assistant (IPPO)", "learned from play beside a scripted leader; reads the goal from your moves",
             True),
    "ippo-people": ("Trained assistant for people (IPPO)", "trained further beside leaders that slip, turn late "
                                                             "and make mistakes", True),
    "ippo-cautious": ("Cautious trained assistant for people (IPPO)", "the trained assistant for people, trained "
                                                                     "further to take fewer wrong blocks and to read "
                                                                     "where your moves lead; it leaves a block it "
                                                                     "is unsure of", True),
    "ippo-1L2F": ("Trained assistant for two (IPPO, 1:2)", "trained as one of two AI followers beside a scripted "
                  "leader; plays only in the 1:2 team", True),
    "ippo-2L1F": ("Trained assistant for two leaders (IPPO, 2:1)", "trained beside two scripted leaders; plays "
                  "only in the 2:1 team", True),
    "ippo-leader": ("Trained leader (IPPO)", "the trained leader playing the follower's part: for researchers", True),
    "bayes": ("Bayesian assistant", "works out the goal from your moves and pickups, and collects once it is sure",
              True),
    "bayes-people": ("Bayesian assistant for people", "the Bayesian assistant, forgiving of late turns and slips, "
                                                      "so a wrong move is not taken for a goal switch", True),
    "copy": ("Copycat", "collects the color of the last block you took that paid", False),
    "oracle": ("Oracle", "sees the goal: for researchers", False),
    "idle": ("Bystander", "walks about and never collects: you play alone", False),
    "random": ("Random mover", "moves at random and collects whatever it steps on", False),
}
"""How the play page names each scripted or shipped follower: label, one-line description, whether it holds a
belief over the goal (that the page may draw)."""


def follower_info(name: str) -> dict:
    """``{value, label, description, has_belief}`` for a follower name. Parameters (``bayes:lapse=0.2``) are
    added to the label; a name not in ``FOLLOWER_INFO`` (a checkpoint path) is labelled by its file name."""
    base, _, params = name.partition(":")
    known = FOLLOWER_INFO.get(base)
    if known is None:
        what = "a trained follower loaded from" if name.endswith(".pt") else "the follower"
        label, description, has_belief = name.rsplit("/", 1)[-1], f"{what} {name}", True
    else:
        label, description, has_belief = known
        label += f" ({params})" if params else ""
    return {"value": name, "label": label, "description": description, "has_belief": has_belief}


def file_part(name: str) -> str:
    """A follower's name as part of a file name: readable, and unique (a checkpoint path by its file's stem and
    a short hash of the whole name, so that two ``latest.pt`` in different runs never share a branch)."""
    stem = re.sub(r"[^A-Za-z0-9_.+-]+", "_", name.rsplit("/", 1)[-1].removesuffix(".pt")) or "follower"
    return stem if stem == name else f"{stem}-{hashlib.sha256(name.encode()).hexdigest()[:8]}"


BRANCHES_PER_MINUTE = 30
"""Branches one client address may ask for a minute."""
MAX_BRANCHES = 2000
"""Branch files the server keeps in ``recordings/branches/``; past it, new branches are refused (503)."""


def create_app(settings: ServerSettings | None = None, study=None) -> FastAPI:
    """The play server; with ``study`` (a ``server.study.run.StudySetup``) it serves that study instead of free play."""
    settings = settings or ServerSettings()
    hub = GameHub(settings)
    catalogue = ReplayCatalogue(settings.replays_dir, settings.released_dir)
    jobs = ReplayJobs(settings.max_exports, int(settings.export_cache_mb * 1e6))
    max_bytes = int(settings.max_replay_mb * 1e6)
    sockets = SocketRegistry(settings)

    service = study.service() if study is not None else None
    if service is not None:
        hub.listeners.append(service)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        hub.start()
        warm = asyncio.create_task(jobs.warm_up())
        try:
            yield
        finally:
            warm.cancel()
            await shutdown(app)
            jobs.close()
            if service is not None:
                service.store.close()

    # The documentation pages are served with local assets (FastAPI's defaults load them from a CDN).
    app = FastAPI(title="ColorGrid play server", version=__version__, lifespan=lifespan,
                  docs_url=None, redoc_url=None)
    app.state.hub, app.state.settings, app.state.sockets = hub, settings, sockets
    if service is not None:
        from server.study.routes import mount_study

        mount_study(app, service, study.admin_token, WEB_DIR, jobs, study.study_file, settings.replays_dir,
                    lambda: sum(g.study is not None for g in hub.games.values()))
    # Requests naming another host are refused (a page on another site cannot reach us by DNS rebinding).
    app.add_middleware(TrustedHostMiddleware, allowed_hosts=settings.hosts, www_redirect=False)

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
    redoc_js = (DOCS_ASSETS / "redoc.standalone.js").read_bytes().replace(REDOC_LOGO.encode(), EMPTY_SVG.encode())

    @app.get("/docs-assets/redoc.standalone.js", include_in_schema=False)
    async def redoc_script():
        # ReDoc's script draws its footer's logo from a CDN: served here without it, so /redoc works offline
        return Response(redoc_js, media_type="text/javascript")

    app.mount("/docs-assets", StaticFiles(directory=DOCS_ASSETS), name="docs-assets")

    @app.get("/favicon.ico", include_in_schema=False)
    async def favicon():
        return FileResponse(WEB_DIR / "favicon.ico", media_type="image/x-icon")

    @app.get("/docs", include_in_schema=False)
    async def swagger_ui():
        return get_swagger_ui_html(openapi_url=app.openapi_url, title=f"{app.title}: API",
                                   swagger_js_url="/docs-assets/swagger-ui-bundle.js",
                                   swagger_css_url="/docs-assets/swagger-ui.css", swagger_favicon_url="/favicon.ico")

    @app.get("/redoc", include_in_schema=False)
    async def redoc():
        return get_redoc_html(openapi_url=app.openapi_url, title=f"{app.title}: API",
                              redoc_js_url="/docs-assets/redoc.standalone.js", redoc_favicon_url="/favicon.ico",
                              with_google_fonts=False)

    @app.get("/api/health")
    async def health():
        """Liveness and load: games running, the limit, tick statistics."""
        lateness = sorted(hub.lateness_ms)  # the last 5000 ticks

        def pct(q):
            return round(lateness[int(q * (len(lateness) - 1))], 2) if lateness else 0.0

        return {"status": "ok", "ready": hub.ready, "version": __version__, "games": hub.live_games(),
                "rooms": len(hub.rooms),
                "max_sessions": settings.max_sessions, "connections": len(sockets.open),
                "follower_pools": len(hub.pools), "tick_hz": settings.tick_hz,
                "inference_pid": hub.inference.pid, "inference_restarts": max(0, hub.inference.generation - 1),
                "inference_failed_starts": hub.inference.failed_starts,
                "tick_lateness_p50_ms": pct(0.5), "tick_lateness_p99_ms": pct(0.99), **hub.stats}

    @app.get("/api/options")
    async def options():
        """What a new game may choose (followers, with labels and descriptions in ``follower_info``, presets with
        their rewards, modes, teams, the horizon's limit) and the defaults, plus what the page needs to draw and
        play: the look of boards and the move keys."""
        presets = {name: env_config(name) for name in sorted(PRESETS)}
        team_followers = {t: hub.team_followers(t) for t in Team}
        return {"followers": list(settings.follower_choices), "default_follower": settings.follower,
                "follower_info": [follower_info(name) for name in settings.follower_choices],
                "presets": list(presets), "default_preset": settings.preset,
                "preset_settings": {name: {"goal_reward": c.goal_reward, "wrong_penalty": c.wrong_penalty,
                                           "horizon": c.horizon} for name, c in presets.items()},
                "modes": [{"value": m.value, "label": m.label} for m in Mode],
                "teams": [{"value": t.value, "label": t.label, "people": t.people, "ai_followers": t.num_followers,
                           "room": t.room,
                           "followers": team_followers[t]}
                          for t in Team if team_followers[t]],
                "room_code_length": ROOM_CODE_LENGTH,
                "horizon": {"default": presets[settings.preset].horizon, "max": MAX_HORIZON},
                "keys": KEY_ACTIONS, "look": look(),
                "tick_hz": settings.tick_hz, "show_belief": settings.show_belief}

    scans: dict = {"at": -1.0, "task": None}

    async def entries() -> dict:
        """The catalogue, scanned on a thread and summarised in the worker processes. Requests arriving
        together share one scan, and a scan under a second old is reused."""
        task = scans["task"]
        if task is None or (task.done() and time.monotonic() - scans["at"] > 1.0):
            scans["at"], scans["task"] = time.monotonic(), asyncio.ensure_future(scan())
        return await asyncio.shield(scans["task"])

    async def scan() -> dict:
        found = await asyncio.to_thread(catalogue.scan)
        for batch in catalogue.missing(found):
            done = await jobs.run(summaries, [(str(e.path), e.id, e.collection) for e in batch], max_bytes)
            for entry, summary in zip(batch, done):
                entry.summary = summary
        return found

    async def entry_or_404(replay_id: str):
        entry = (await entries()).get(replay_id) if ID_PATTERN.match(replay_id) else None
        if entry is None:
            raise HTTPException(404, f"no replay with id {replay_id!r}")
        return entry

    @app.get("/api/replays")
    async def list_replays(source: str | None = None, follower: str | None = None, collection: str | None = None,
                           setting: str | None = None, branch_of: str | None = Query(None, max_length=200),
                           sort: str = Query("created", pattern="^(created|team_score)$"),
                           order: str = Query("desc", pattern="^(asc|desc)$"),
                           offset: int = Query(0, ge=0), limit: int = Query(50, ge=1, le=500)):
        """Recorded and released replays, filtered, sorted and paginated; broken files are listed with their error."""
        items = [e.summary for e in (await entries()).values()]
        if source:
            items = [i for i in items if i.get("source") == source]
        if branch_of:  # the branches of a replay: a part of the parent's id, any case
            items = [i for i in items if i.get("branch_of") and branch_of.lower() in str(i["branch_of"]["parent"]).lower()]
        if follower:  # a part of the follower's name, any case ("ippo" finds ippo and ippo@3000)
            items = [i for i in items if follower.lower() in str(i.get("follower") or "").lower()]
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

    @app.get("/api/replays/{replay_id}", responses={404: {}, 422: {}})
    async def get_replay(replay_id: str):
        """One replay file, as stored (422 with the problem for a file that does not load)."""
        entry = await entry_or_404(replay_id)
        if entry.problem:
            raise HTTPException(422, f"replay {replay_id!r} cannot be used: {entry.problem}")
        return FileResponse(entry.path, media_type="application/json")

    @app.get("/api/replays/{replay_id}/timeline", responses={404: {}, 503: {}})
    async def replay_timeline(replay_id: str):
        """What the replay player draws: verification, one board per step, belief curves, events, key log."""
        entry = await entry_or_404(replay_id)
        if entry.problem:
            return {"id": replay_id, "verified": False, "problem": entry.problem}
        return FileResponse(await jobs.timeline(entry.path, replay_id, entry.mtime, max_bytes),
                            media_type="application/json")

    @app.get("/api/replays/{replay_id}/export", responses={404: {}, 422: {}, 503: {}})
    async def export_replay(replay_id: str, format: str = Query("gif", pattern="^(gif|mp4)$")):
        """The replay as a GIF or MP4, made on the server (cached; 503 with Retry-After while busy)."""
        entry = await entry_or_404(replay_id)
        if entry.problem:
            raise HTTPException(422, f"replay cannot be exported: {entry.problem}")
        try:
            out = await jobs.export(entry.path, replay_id, entry.mtime, format, max_bytes)
        except ValueError as err:
            raise HTTPException(422, f"replay cannot be exported: {err}") from None
        media = "image/gif" if format == "gif" else "video/mp4"
        return FileResponse(out, media_type=media, filename=f"{replay_id}.{format}")

    branching: dict = {}  # branch file -> the job making it: requests for the same branch share one
    branch_limits = AddressLimits(BRANCHES_PER_MINUTE / 60.0, burst=BRANCHES_PER_MINUTE)

    @app.post("/api/replays/{replay_id}/branch", responses={400: {}, 404: {}, 422: {}, 429: {}, 503: {}})
    async def branch_replay(replay_id: str, body: BranchRequest, request: Request):
        """The replay continued from ``step`` with another of the server's followers (the leader replays its
        recorded moves), saved under ``branches/`` in the recordings folder and made once: ``{"id": ...}``."""
        entry = await entry_or_404(replay_id)
        if entry.problem:
            raise HTTPException(422, f"replay {replay_id!r} cannot be branched: {entry.problem}")
        if body.follower not in settings.follower_choices:  # names only: a path from the web would read files
            raise HTTPException(400, f"follower must be one of {list(settings.follower_choices)}, "
                                     f"got {body.follower!r}")
        if replay_id.startswith("branches--"):
            raise HTTPException(422, "a branch cannot be branched again: branch the original replay")
        if entry.summary.get("team", "1:1") != "1:1":
            raise HTTPException(422, f"only 1:1 replays can be branched; this one's team is {entry.summary['team']}")
        if not branch_limits.bucket(request.client.host if request.client else "?").allow():
            raise HTTPException(429, f"too many branches from this address: at most {BRANCHES_PER_MINUTE} a minute")
        steps = entry.summary["steps"]
        if not 0 <= body.step <= steps:
            raise HTTPException(422, f"step must be in [0, {steps}] (the replay has {steps} steps), got {body.step}")
        name = f"{replay_id}--branch{body.step}-{file_part(body.follower)}"
        branch_id = f"branches--{name}"
        if not ID_PATTERN.match(branch_id):
            raise HTTPException(422, f"replay {replay_id!r} cannot be branched: its branch's id would be too long")
        out = settings.replays_dir / "branches" / f"{name}{SUFFIX}"
        if not out.exists() and sum(1 for _ in out.parent.glob(f"*{SUFFIX}")) >= MAX_BRANCHES:
            raise Busy(f"{MAX_BRANCHES} branches already: remove some from {out.parent}", retry_after_s=60)
        if not out.exists():
            running = branching.get(out)
            if running is None:
                running = asyncio.ensure_future(jobs.run(branch_file, str(entry.path), str(out), body.step,
                                                         body.follower, replay_id, max_bytes))
                branching[out] = running
                running.add_done_callback(lambda _: branching.pop(out, None))
            problem = await asyncio.shield(running)
            if problem is not None:
                raise HTTPException(422, f"replay {replay_id!r} cannot be branched: {problem}")
            scans["task"] = None  # the next request lists the new file
        return {"id": branch_id}

    @app.exception_handler(Busy)
    async def busy(request, err: Busy):
        return JSONResponse({"detail": str(err)}, status_code=503, headers={"Retry-After": str(err.retry_after_s)})

    @app.websocket("/ws/play")
    async def play_socket(ws: WebSocket):
        refusal = sockets.refusal(ws)
        if refusal is not None:  # before accepting: the browser sees the handshake fail
            log.warning("refused a play socket: %s", refusal[1])
            await ws.close(refusal[0], refusal[1])
            return
        await ws.accept()
        conn = Connection(ws, settings, sockets.new_games.bucket(ws.client.host if ws.client else "?"), service)
        sockets.open.add(conn)
        writer = asyncio.create_task(conn.writer())
        try:
            await conn.serve(hub)
        except WebSocketDisconnect:
            pass
        finally:
            sockets.open.discard(conn)
            conn.closed = True
            writer.cancel()
            if conn.game is not None:
                hub.disconnect(conn.game, conn)
            if conn.room is not None:
                await hub.leave_room(conn.room, conn)

    return app


async def shutdown(app: FastAPI) -> None:
    """Save every live game, tell each player (``game_over``, reason ``server_shutdown``) and then
    close its socket. Runs before the web server closes connections; calling it again does nothing."""
    told = await app.state.hub.stop()
    await asyncio.gather(*(conn.close_after_sending(CLOSE_RESTART, "server shutdown") for conn in told),
                         return_exceptions=True)


class SocketRegistry:
    """Who may open a play socket: allowed origins, a cap on open sockets, a game-creation rate per address."""

    def __init__(self, settings: ServerSettings):
        self.settings = settings
        self.open: set[Connection] = set()
        rate = settings.new_games_per_minute
        self.new_games = AddressLimits(rate / 60.0, burst=rate)

    def refusal(self, ws: WebSocket) -> tuple[int, str] | None:
        """Why this handshake is refused (close code and reason), or None."""
        origin = ws.headers.get("origin")
        if origin is not None and not self.origin_allowed(origin, ws.headers.get("host", "")):
            return CLOSE_POLICY, f"origin {origin!r} is not allowed"
        if len(self.open) >= self.settings.max_connections:
            return CLOSE_TRY_LATER, f"too many connections ({len(self.open)}); try again later"
        return None

    def origin_allowed(self, origin: str, host: str) -> bool:
        """The server's own pages (the origin names the host the request went to), or a configured origin."""
        allowed = self.settings.allowed_origins
        if "*" in allowed or origin.rstrip("/") in allowed:
            return True
        parts = urlsplit(origin)
        return parts.scheme in ("http", "https") and bool(host) and parts.netloc.lower() == host.lower()


class Connection:
    """One browser tab's WebSocket: validation, rate limits, and an outgoing queue per socket."""

    def __init__(self, ws: WebSocket, settings: ServerSettings, new_games: TokenBucket, study=None):
        self.ws, self.settings, self.new_games, self.study = ws, settings, new_games, study
        self.game = None
        self.room = None  # the room this tab waits in, before its game starts
        self.closed = False
        self.outbox: asyncio.Queue = asyncio.Queue(maxsize=256)
        self.messages = TokenBucket(settings.max_messages_per_s, burst=2 * settings.max_messages_per_s)
        self.flood = FloodRule(int(FLOOD_WINDOW_S * settings.max_messages_per_s), FLOOD_WINDOW_S)
        self.last_refusal_notice = 0.0

    async def send(self, message: dict) -> None:
        if self.closed:
            raise ConnectionError("socket closed")
        if self.outbox.full():  # a slow reader: drop the oldest queued message, keep the newest state
            self.outbox.get_nowait()
            self.outbox.task_done()
        self.outbox.put_nowait(message)

    def detach(self) -> None:
        """This tab no longer plays its game or waits in its room: another connection took the game over
        (``rejoin``), the person left it, or the room closed."""
        self.game = self.room = None

    def attach(self, game) -> None:
        """The room's game started: this tab plays it."""
        self.game, self.room = game, None

    async def writer(self) -> None:
        while True:
            message = await self.outbox.get()
            try:
                text = json.dumps(message, allow_nan=False)
            except ValueError:  # e.g. a follower's belief gone NaN: this message is lost, the socket is not
                log.exception("could not encode a %s message", message.get("type"))
                text = json.dumps(error("internal", "the server could not send a message; the game goes on"))
            try:
                await self.ws.send_text(text)
            finally:
                self.outbox.task_done()

    async def close_after_sending(self, code: int, reason: str, timeout_s: float = 2.0) -> None:
        """Close once what is queued (the ``game_over``) has gone out, or after ``timeout_s``."""
        try:
            await asyncio.wait_for(self.outbox.join(), timeout_s)
        except asyncio.TimeoutError:
            pass
        self.closed = True
        try:
            await self.ws.close(code, reason)
        except Exception:  # already closed by the client
            pass

    async def receive(self) -> dict:
        """The next frame; a socket with no game or room that stays silent for ``connection_idle_s`` is closed."""
        if self.game is not None or self.room is not None:
            return await self.ws.receive()
        try:
            return await asyncio.wait_for(self.ws.receive(), self.settings.connection_idle_s)
        except asyncio.TimeoutError:
            await self.ws.close(CLOSE_GOING_AWAY, "idle: no game was started")
            raise WebSocketDisconnect(CLOSE_GOING_AWAY) from None

    async def serve(self, hub: GameHub) -> None:
        while True:
            raw = await self.receive()
            if raw["type"] == "websocket.disconnect":
                raise WebSocketDisconnect(raw.get("code", 1000))
            text = raw.get("text")
            size = len(text.encode()) if text is not None else len(raw.get("bytes") or b"")
            if not self.messages.allow():
                if self.flood.refuse():
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
            try:
                await self.handle(hub, text)
            except Exception:  # a bug must cost this message, not the connection or the game
                log.exception("could not handle a message")
                await self.send(error("internal", "the server could not handle this message; the game goes on"))

    async def handle(self, hub: GameHub, text: str) -> None:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            await self.send(error("bad_json", f"not valid JSON: {err.msg} at position {err.pos}"))
            return
        except RecursionError:
            await self.send(error("bad_json", "not accepted: JSON nested too deeply"))
            return
        if not isinstance(data, dict) or data.get("type") not in CLIENT_TYPES:
            kind = data.get("type") if isinstance(data, dict) else None
            shown = repr(kind) if isinstance(kind, str) and len(kind) <= 40 else type(kind).__name__
            await self.send(error("unknown_type", f"unknown message type {shown}; expected one of {list(CLIENT_TYPES)}"))
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
        except RoomError as err:
            await self.send(error(err.code, str(err)))
        except ValueError as err:
            await self.send(error("rejected", str(err)))

    async def dispatch(self, hub: GameHub, msg) -> None:
        if isinstance(msg, Ping):
            await self.send({"type": "pong", "t_server": time.time() * 1000})
        elif isinstance(msg, (NewGame, Rejoin, CreateRoom, JoinRoom)):
            if self.game is not None and hub.controls(self.game, self):
                raise ValueError("this connection already has a live game; send quit first")
            if hub.room_of(self, self.room) is not None:
                raise ValueError(f"this connection waits in room {self.room.code}; send quit to leave it first")
            if self.study is not None and isinstance(msg, (CreateRoom, JoinRoom)):
                raise ValueError("this server runs a study: games start from the study page")
            # joining a room counts as a new game: room codes cannot be tried quickly
            if not isinstance(msg, Rejoin) and not self.new_games.allow():
                raise ValueError(f"too many new games from this address: at most "
                                 f"{self.settings.new_games_per_minute:g} a minute (rooms opened and joined "
                                 f"count too); try again in {self.new_games.retry_after():.0f} s")
            if isinstance(msg, NewGame):
                self.game = await self.new_game(hub, msg)
            elif isinstance(msg, CreateRoom):
                self.room = await hub.create_room(msg.team, msg.follower, msg.preset, msg.mode, msg.horizon,
                                                  msg.show_belief, self, self.client_info(msg.viewport))
            elif isinstance(msg, JoinRoom):
                self.room = await hub.join_room(msg.code, self, self.client_info(msg.viewport))
            else:
                self.game = await hub.rejoin(msg.game_id, msg.token, self)
        elif hub.room_of(self, self.room) is not None:  # waiting in a room
            if isinstance(msg, Ready):
                await hub.set_ready(self.room, self, msg.ready)
            elif isinstance(msg, Quit):
                await hub.leave_room(self.room, self)
                self.room = None
            else:
                raise ValueError(f"the game of room {self.room.code} has not started: send ready (or quit to leave)")
        elif isinstance(msg, Ready):
            raise ValueError("no room on this connection: send create_room or join_room first")
        elif hub.played_to_the_end(self.game, self):  # keys on their way at the end are logged, not refused
            seat = self.game.seat_of(self)
            if isinstance(msg, Key) and (problem := self.game.press(msg.key, msg.seq, msg.t_client, seat)):
                await self.send(error("bad_key", problem))
            elif isinstance(msg, PageEvent):
                self.game.page_event(msg.event, msg.visible, msg.t_client, seat)
        elif self.game is None or not hub.controls(self.game, self):
            raise ValueError("no live game on this connection: send new_game or rejoin first")
        elif isinstance(msg, Key):
            problem = await hub.key(self.game, msg.key, msg.seq, msg.t_client, self.game.seat_of(self))
            if problem:
                await self.send(error("bad_key", problem))
        elif isinstance(msg, PageEvent):
            self.game.page_event(msg.event, msg.visible, msg.t_client, self.game.seat_of(self))
        elif isinstance(msg, Quit):
            if self.game.study is not None:
                raise ValueError("a study's game cannot be ended early")
            await hub.quit(self.game, self)

    def client_info(self, viewport) -> dict:
        """What a replay records of the page: its user agent and, when sent, its viewport."""
        return {"user_agent": self.ws.headers.get("user-agent", "")[:500],
                "viewport": list(viewport) if viewport else None}

    async def new_game(self, hub: GameHub, msg: NewGame):
        client_info = self.client_info(msg.viewport)
        if self.study is None:
            if msg.study is not None:
                raise ValueError("this server runs no study")
            return await hub.new_game(msg.follower, msg.preset, msg.mode, msg.horizon, msg.show_belief, self,
                                      client_info=client_info, team=msg.team, followers=msg.followers)
        if msg.study is None:
            raise ValueError("this server runs a study: games start from the study page")
        if msg.team != Team.ONE_TO_ONE:
            raise ValueError("a study's games are one person with one AI follower (team 1:1); the study file sets "
                             "everything else")
        from server.study.service import Invalid as StudyInvalid, Refused as StudyRefused

        try:
            game, meta = await asyncio.get_running_loop().run_in_executor(
                None, self.study.game_for, msg.study.participant, msg.study.session)
        except (StudyRefused, StudyInvalid) as err:
            raise ValueError(str(err)) from None
        return await hub.new_game(game.follower, game.preset, Mode(game.mode), game.horizon, game.show_belief, self,
                                  tick_hz=game.tick_hz, study=meta, client_info=client_info)
