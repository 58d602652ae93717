"""One play WebSocket: who may open one, and what a connection does with each frame before the hub sees it.

``SocketRegistry`` refuses handshakes (origin, too many sockets) and limits new games per address;
``Connection`` is one browser tab's socket: rate and size limits, JSON and message validation
(``server.protocol``), an outgoing queue, and each message handed to the ``GameHub`` that plays the game.
A socket serves one game: it is closed once its ``game_over`` is out, and one with no game that sends nothing
for ``connection_idle_s`` is closed too.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Awaitable, Callable
from enum import StrEnum
from urllib.parse import urlsplit

from fastapi import WebSocket, WebSocketDisconnect
from pydantic import ValidationError

from server.keylog import BadSeq
from server.limits import AddressLimits, FloodRule, TokenBucket
from server.messages import Error, Full, Pong
from server.play.hub import GameHub, ServerFull
from server.protocol import (
    CLIENT_TYPES,
    Belief,
    ClientModel,
    CreateRoom,
    JoinRoom,
    Key,
    NewGame,
    PageEvent,
    Ping,
    ProbeAnswer,
    Quit,
    Ready,
    Rejoin,
    client_message,
)
from server.rooms import RoomError
from server.settings import ServerSettings
from server.stated import StatementError

CLOSE_NORMAL = 1000  # its game is over (after game_over)
CLOSE_POLICY = 1008  # a flood, or a page from an origin that is not allowed
CLOSE_GOING_AWAY = 1001  # idle without a game
CLOSE_RESTART = 1012  # the server is stopping (after game_over)
CLOSE_TRY_LATER = 1013  # too many connections
FLOOD_WINDOW_S = 5.0
log = logging.getLogger("colorgrid.server")


class Stage(StrEnum):
    """Where a connection stands, which decides the messages it takes (``HANDLERS``)."""

    STARTING = "starting"  # no game or room yet (or no longer: it ended, was taken over, or the room closed)
    IN_ROOM = "in a room"  # waiting in a room for its game
    IN_GAME = "in a game"  # playing a seat of a game (live, or taking its late keys)


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

    def __init__(self, ws: WebSocket, hub: GameHub, new_games: TokenBucket):
        self.ws, self.hub, self.new_games = ws, hub, new_games
        self.settings = settings = hub.settings
        self.game = None
        self.room = None  # the room this tab waits in, before its game starts
        self.closed = False
        self.over = False  # its game_over was sent: the socket closes once it is out, and starts no other game
        self.quiet_since = time.monotonic()  # its last message, or the moment it lost its game or room
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
        if message["type"] == "game_over":
            self.over = True

    async def send_error(self, code: str, message: str) -> None:
        """Refuse a message, or report a problem, with an ``error``; the game goes on."""
        await self.send(Error(type="error", code=code, message=message).wire())

    def detach(self) -> None:
        """This tab no longer plays its game or waits in its room: another connection took the game over
        (``rejoin``), the person left it, or the room closed."""
        self.game = self.room = None
        self.quiet_since = time.monotonic()

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
                text = json.dumps(Error(type="error", code="internal",
                                        message="the server could not send a message; the game goes on").wire())
            try:
                await self.ws.send_text(text)
            finally:
                self.outbox.task_done()
            if message["type"] == "game_over" and not self.hub.stopped:  # stopping: closed with CLOSE_RESTART
                self.closed = True  # one game a socket: the page opens a new one for the next
                try:
                    await self.ws.close(CLOSE_NORMAL, "game over")
                except Exception:  # already closed by the client
                    pass
                return

    async def close_after_sending(self, code: int, reason: str, timeout_s: float = 2.0) -> None:
        """Close once what is queued (the ``game_over``) has gone out, or after ``timeout_s``."""
        try:
            await asyncio.wait_for(self.outbox.join(), timeout_s)
        except TimeoutError:
            pass
        self.closed = True
        try:
            await self.ws.close(code, reason)
        except Exception:  # already closed by the client
            pass

    def busy(self) -> bool:
        """Whether this socket plays a game (live, or taking its late keys) or waits in a room (or for its game)."""
        if self.hub.seat_of(self.game, self) is not None:
            return True
        room = self.room
        return room is not None and (room.opening or self.hub.room_of(self, room) is not None)

    async def receive(self) -> dict:
        """The next frame. A socket with no game or room (none started, or its game taken over by another, or its
        room closed) that has sent nothing for ``connection_idle_s`` is closed."""
        limit = self.settings.connection_idle_s
        while True:
            quiet = time.monotonic() - self.quiet_since
            if not self.busy() and quiet >= limit:
                self.closed = True
                await self.ws.close(CLOSE_GOING_AWAY, "idle: no game")
                raise WebSocketDisconnect(CLOSE_GOING_AWAY)
            try:  # a busy socket is looked at again every ``limit`` s: its game may end or be taken over meanwhile
                raw = await asyncio.wait_for(self.ws.receive(), limit if self.busy() else limit - quiet)
            except TimeoutError:
                continue
            self.quiet_since = time.monotonic()
            return raw

    async def serve(self) -> None:
        """Take this socket's frames until it closes (``WebSocketDisconnect``)."""
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
                    rate = self.settings.max_messages_per_s
                    await self.send_error("rate_limited", f"too many messages: at most {rate:g}/s; extra ones are "
                                                          "refused")
                continue
            if size > self.settings.max_message_bytes:
                await self.send_error("too_large", f"message of {size} bytes refused; the limit is "
                                                   f"{self.settings.max_message_bytes}")
                continue
            if text is None:
                await self.send_error("bad_json", "binary messages are not supported; send JSON text")
                continue
            try:
                await self.handle(text)
            except Exception:  # a bug must cost this message, not the connection or the game
                log.exception("could not handle a message")
                await self.send_error("internal", "the server could not handle this message; the game goes on")

    async def handle(self, text: str) -> None:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            await self.send_error("bad_json", f"not valid JSON: {err.msg} at position {err.pos}")
            return
        except RecursionError:
            await self.send_error("bad_json", "not accepted: JSON nested too deeply")
            return
        if not isinstance(data, dict) or data.get("type") not in CLIENT_TYPES:
            kind = data.get("type") if isinstance(data, dict) else None
            shown = repr(kind) if isinstance(kind, str) and len(kind) <= 40 else type(kind).__name__
            await self.send_error("unknown_type", f"unknown message type {shown}; expected one of "
                                                  f"{list(CLIENT_TYPES)}")
            return
        try:
            msg = client_message.validate_python(data)
        except ValidationError as err:
            first = err.errors()[0]
            where = ".".join(str(p) for p in first["loc"][1:]) or "message"
            await self.send_error("invalid_message", f"{data['type']}: {where}: {first['msg']}")
            return
        try:
            await self.dispatch(msg)
        except BadSeq as err:
            await self.send_error("bad_seq", str(err))
        except StatementError as err:
            await self.send_error(err.code, str(err))
        except ServerFull as err:
            await self.send(Full(type="full", message=str(err)).wire())
        except RoomError as err:
            await self.send_error(err.code, str(err))
        except ValueError as err:
            await self.send_error("rejected", str(err))

    def stage(self) -> Stage:
        """Where this connection stands: waiting in a room, playing a seat of a game, or neither."""
        if self.hub.room_of(self, self.room) is not None:
            return Stage.IN_ROOM
        return Stage.STARTING if self.hub.seat_of(self.game, self) is None else Stage.IN_GAME

    async def dispatch(self, msg: ClientModel) -> None:
        """Hand ``msg`` to its handler for this connection's stage (``HANDLERS``); one the stage does not take is
        refused (``ValueError``), saying what the stage takes."""
        stage = self.stage()
        handler = HANDLERS[stage].get(type(msg))
        if handler is None:
            raise ValueError(self.refusal(stage, msg))
        await handler(self, msg)

    def refusal(self, stage: Stage, msg: ClientModel) -> str:
        """Why ``msg`` is not taken at ``stage``."""
        if stage == Stage.IN_ROOM:
            return f"the game of room {self.room.code} has not started: send ready (or quit to leave)"
        if isinstance(msg, Ready):
            return "no room on this connection: send create_room or join_room first"
        return "no live game on this connection: send new_game or rejoin first"

    # ------------------------------------------------------------ at any stage
    async def on_ping(self, msg: Ping) -> None:
        await self.send(Pong(type="pong", t_server=time.time() * 1000).wire())
        if msg.round_trip_ms is not None and self.game is not None and self.hub.controls(self.game, self):
            self.hub.round_trip(self.game, msg.round_trip_ms)  # during a game: a study keeps it (its exclusions)

    def check_start(self, room: bool = False, counted: bool = True) -> None:
        """Whether this connection may start a game, or open or join a ``room``, now (``ValueError`` says why not);
        ``counted``: it counts toward the address's new games."""
        if self.over:
            raise ValueError("this connection's game is over and it is closing: open a new connection for the "
                             "next game")
        if self.game is not None and self.hub.controls(self.game, self):
            raise ValueError("this connection already has a live game; send quit first")
        if self.hub.room_of(self, self.room) is not None:
            raise ValueError(f"this connection waits in room {self.room.code}; send quit to leave it first")
        refusal = self.hub.source.room_refusal  # an application choosing people's games may keep them apart
        if room and refusal is not None:
            raise ValueError(refusal)
        # joining a room counts as a new game: room codes cannot be tried quickly
        if counted and not self.new_games.allow():
            raise ValueError(f"too many new games from this address: at most "
                             f"{self.settings.new_games_per_minute:g} a minute (rooms opened and joined "
                             f"count too); try again in {self.new_games.retry_after():.0f} s")

    async def on_new_game(self, msg: NewGame) -> None:
        self.check_start()  # the player's choice, or the game an application chooses for them
        self.game = await self.hub.source.new_game(self.hub.new_game, msg, self, self.client_info(msg.viewport))

    async def on_create_room(self, msg: CreateRoom) -> None:
        self.check_start(room=True)
        self.room = await self.hub.create_room(msg.team, msg.follower, msg.preset, msg.mode, msg.horizon,
                                               msg.show_belief, self, self.client_info(msg.viewport))

    async def on_join_room(self, msg: JoinRoom) -> None:
        self.check_start(room=True)
        self.room = await self.hub.join_room(msg.code, self, self.client_info(msg.viewport))

    async def on_rejoin(self, msg: Rejoin) -> None:
        self.check_start(counted=False)
        self.game = await self.hub.rejoin(msg.game_id, msg.token, self)

    # ------------------------------------------------------------ waiting in a room
    async def on_ready(self, msg: Ready) -> None:
        await self.hub.set_ready(self.room, self, msg.ready)

    async def on_leave_room(self, msg: Quit) -> None:
        await self.hub.leave_room(self.room, self)
        self.room = None

    # ------------------------------------------------------------ playing a seat
    async def on_key(self, msg: Key) -> None:  # keys on their way at a real-time game's end are logged, not refused
        if problem := await self.hub.key(self.game, msg.key, msg.seq, msg.t_client, self.hub.seat_of(self.game, self)):
            await self.send_error("bad_key", problem)

    async def on_belief(self, msg: Belief) -> None:
        self.game.state_belief(msg.color, msg.t_client)

    async def on_probe_answer(self, msg: ProbeAnswer) -> None:
        await self.hub.answer_probe(self.game, msg.probe, msg.color, msg.confidence, msg.t_client)

    async def on_page_event(self, msg: PageEvent) -> None:
        self.game.page_event(msg.event, msg.visible, msg.t_client, self.hub.seat_of(self.game, self))

    async def on_quit(self, msg: Quit) -> None:
        if not self.hub.controls(self.game, self):  # a quit after the last step changes nothing
            return
        if self.hub.source.quit_refusal is not None:
            raise ValueError(self.hub.source.quit_refusal)
        await self.hub.quit(self.game, self)

    def client_info(self, viewport) -> dict:
        """What a replay records of the page: its user agent and, when sent, its viewport."""
        return {"user_agent": self.ws.headers.get("user-agent", "")[:500],
                "viewport": list(viewport) if viewport else None}


_ANY_STAGE = {Ping: Connection.on_ping, NewGame: Connection.on_new_game, CreateRoom: Connection.on_create_room,
              JoinRoom: Connection.on_join_room, Rejoin: Connection.on_rejoin}
HANDLERS: dict[Stage, dict[type, Callable[[Connection, ClientModel], Awaitable[None]]]] = {
    Stage.STARTING: _ANY_STAGE,
    Stage.IN_ROOM: {**_ANY_STAGE, Ready: Connection.on_ready, Quit: Connection.on_leave_room},
    Stage.IN_GAME: {**_ANY_STAGE, Key: Connection.on_key, Belief: Connection.on_belief,
                    ProbeAnswer: Connection.on_probe_answer, PageEvent: Connection.on_page_event,
                    Quit: Connection.on_quit},
}
"""Each stage's handler of each message it takes (``Connection.dispatch``): ping and the starts at any stage (a start
says itself when it may not be made now), ready and quit in a room, the game's messages in a game."""
