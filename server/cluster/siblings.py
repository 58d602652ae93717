"""A backend as one of several behind HAProxy: the routing cookie its pages set, a room held by a sibling, a
participant's game run by a sibling, and the health of the whole cluster.

``join_cluster(app, membership)`` adds this to a play server: its ``Backend.member`` says which cluster it is in
(the plan file, ``server.cluster.plan``) and its name there. Backends learn about each other by asking each
other over HTTP, at the addresses in the plan file, only when asked themselves (``/api/health``, a room link,
the page of a participant whose game never ended and is not running here):
nothing runs in the background and a sibling that is down is reported as down, never waited for long.
"""

from __future__ import annotations

import asyncio
import json
import re
import secrets
import urllib.error
import urllib.parse
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from typing import Annotated

from fastapi import APIRouter, FastAPI, Header, HTTPException, Request
from fastapi.responses import RedirectResponse, Response

from server.backend import CurrentBackend
from server.cluster.haproxy import BACKEND_COOKIE, HEALTH_CHECK, PLAIN_HOST, ROUTE_COOKIE
from server.cluster.plan import Member, Membership
from server.protocol import normalise_room_code

ASK_TIMEOUT_S = 1.5
"""How long a backend waits for a sibling's answer before it reports it as down."""
PAGES = ("/", "/study")
"""The pages that set the routing cookie (every later request of the page carries it)."""
KEY = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
"""What a routing key may be (a participant id is one: a plugin's ``routing_params`` name it)."""
SUMMED = ("games", "rooms", "connections", "max_sessions")
"""Counts that add up over the backends."""
REPORTED = ("ready", "pid", "restarts", *SUMMED, "tick_lateness_p50_ms", "tick_lateness_p99_ms", "max_lateness_ms",
            "ticks", "late_ticks", "deadline_misses", "inference_restarts", "games_saved", "save_failures")
"""What the cluster's health reports of each backend (from its own ``/api/health``)."""


def ask(base: str, path: str, secret: str | None = None) -> tuple[int, dict]:
    """A play server's answer to ``GET path`` (status and JSON body) at ``base`` (``http://HOST:PORT``, a sibling
    or the proxy); status 0 with the problem when it did not answer. Blocking: called in a thread."""
    headers = {"Host": PLAIN_HOST, **({"Authorization": f"Bearer {secret}"} if secret else {})}
    request = urllib.request.Request(f"{base}{path}", headers=headers)
    try:
        with urllib.request.urlopen(request, timeout=ASK_TIMEOUT_S) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as err:
        try:
            return err.code, json.loads(err.read())
        except ValueError:
            return err.code, {}
    except (OSError, ValueError) as err:
        return 0, {"problem": str(getattr(err, "reason", err))}


async def cluster_health(membership: Membership, own: dict) -> dict:
    """``backends``: every backend of the plan, up or not, with its load and tick lateness; ``cluster``: the
    counts added up. This process reports from ``own`` (its own health), the others as they answer their
    ``/api/health?scope=backend``."""
    plan = membership.plan()

    async def report(member: Member) -> dict:
        status, body = (200, own) if member.name == membership.name else await asyncio.to_thread(
            ask, member.url, HEALTH_CHECK)
        entry = {"name": member.name, "address": member.address, "up": status in (200, 503) and "ready" in body}
        entry.update({k: body[k] for k in REPORTED if k in body} if entry["up"] else
                     {"problem": body.get("problem") or f"answered {status}"})
        return entry

    backends = await asyncio.gather(*(report(m) for m in plan.members))
    up = [b for b in backends if b["up"]]
    return {"backends": backends,
            "cluster": {"size": len(backends), "up": len(up), "ready": sum(bool(b.get("ready")) for b in up),
                        **{k: sum(b.get(k, 0) for b in up) for k in SUMMED},
                        "tick_lateness_p99_ms": max((b.get("tick_lateness_p99_ms", 0.0) for b in up), default=0.0)}}


def game_elsewhere(membership: Membership, pid: str) -> dict | None:
    """The study game a sibling runs for participant ``pid``: ``{game_id, token, backend}`` (the sibling's name),
    or None when none does (or none that runs it answers). Blocking: called in a worker thread."""
    plan = membership.plan()
    others = [m for m in plan.members if m.name != membership.name]
    if not others:
        return None
    path = f"/api/cluster/live/{urllib.parse.quote(pid, safe='')}"
    with ThreadPoolExecutor(len(others)) as pool:
        answers = list(pool.map(lambda m: ask(m.url, path, plan.secret), others))
    return next(({"game_id": body["game_id"], "token": body["token"], "backend": m.name}
                 for m, (status, body) in zip(others, answers) if status == 200 and "game_id" in body), None)


def pin(response: Response, name: str) -> None:
    """Send this browser's next requests to backend ``name`` (HAProxy's cookie persistence, while it is up)."""
    response.set_cookie(BACKEND_COOKIE, name, httponly=True, samesite="lax")


async def room_holder(membership: Membership, code: str) -> Member | None:
    """The sibling whose waiting room has ``code``, if one has."""
    plan = membership.plan()
    others = [m for m in plan.members if m.name != membership.name]
    answers = await asyncio.gather(*(asyncio.to_thread(ask, m.url, f"/api/cluster/rooms/{code}", plan.secret)
                                     for m in others))
    return next((m for m, (status, _) in zip(others, answers) if status == 200), None)


def route_key(request: Request, id_params: tuple[str, ...]) -> str:
    """The key HAProxy hashes for this browser: the participant id of the link (a study's ``id_params``), else the
    key it already has, else a new one of its own."""
    for name in id_params:
        value = request.query_params.get(name)
        if value and KEY.match(value):
            return value
    kept = request.cookies.get(ROUTE_COOKIE, "")
    return kept if KEY.match(kept) else secrets.token_urlsafe(12)


router = APIRouter(include_in_schema=False)


def sibling_only(backend, authorization: str | None) -> None:
    """Only the cluster's backends may ask (the plan's secret); HAProxy does not pass ``/api/cluster/`` on either."""
    secret = backend.member.plan().secret
    if not secrets.compare_digest((authorization or "").encode(), f"Bearer {secret}".encode()):
        raise HTTPException(403, "only the cluster's backends may ask this")


@router.get("/api/cluster/rooms/{code}")
async def room_here(code: str, backend: CurrentBackend, authorization: Annotated[str | None, Header()] = None):
    """A sibling asks whether this backend holds the waiting room ``code`` (200) or not (404)."""
    sibling_only(backend, authorization)
    if code not in backend.hub.rooms:
        raise HTTPException(404, "no such room here")
    return {"room": code}


@router.get("/api/cluster/live/{pid}")
async def game_here(pid: str, backend: CurrentBackend, authorization: Annotated[str | None, Header()] = None):
    """A sibling asks whether this backend runs participant ``pid``'s study game: 200 with what rejoins it (its id
    and token), or 404."""
    sibling_only(backend, authorization)
    game = backend.hub.source.game_of(pid)
    if game is None or game.finished:
        raise HTTPException(404, "no game of this participant runs here")
    return {"game_id": game.game_id, "token": game.token}


def join_cluster(app: FastAPI, membership: Membership) -> None:
    """Make ``app``'s backend one of a cluster: its pages set the routing cookie, a room link is sent to the
    sibling holding the room, and ``/api/health`` reports every backend."""
    backend = app.state.backend
    backend.member = membership
    plugin = backend.shared.plugin
    id_params = tuple(plugin.routing_params) if plugin is not None else ()
    app.include_router(router)
    backend.hub.source.elsewhere = lambda pid: game_elsewhere(membership, pid)  # a person's game may run in a sibling

    @app.middleware("http")
    async def routing_cookie(request: Request, call_next):
        if request.method != "GET" or request.url.path not in PAGES:
            return await call_next(request)
        code = normalise_room_code(request.query_params.get("room", "")) if plugin is None else None
        if code is not None and code not in backend.hub.rooms:
            moved = await send_to_room(request, code)
            if moved is not None:
                return moved
        response = await call_next(request)
        key = route_key(request, id_params)
        if key != request.cookies.get(ROUTE_COOKIE):
            response.set_cookie(ROUTE_COOKIE, key, httponly=True, samesite="lax")
        return response

    async def send_to_room(request: Request, code: str):
        """A room link opened on a backend that does not hold the room: back to the same link, with the cookie
        that makes HAProxy send it to the sibling that does. A look-up costs what joining a room costs (one of
        the address's new games a minute), so that room codes cannot be tried faster here than by joining."""
        address = request.client.host if request.client else "?"
        if not backend.sockets.new_games.bucket(address).allow():
            return None
        holder = await room_holder(membership, code)
        if holder is None or request.cookies.get(BACKEND_COOKIE) == holder.name:  # HAProxy did not follow it
            return None
        moved = RedirectResponse(f"{request.url.path}?{request.url.query}", status_code=307)
        pin(moved, holder.name)
        return moved
