"""The replay API: the list of recorded and released replays, one replay's file and timeline, GIF/MP4 exports,
what-if branches and a follower-seat game's person beside an AI follower. The work runs in this process's replay workers (``server.jobs``); busy ones answer 503
with ``Retry-After``."""

from __future__ import annotations

import hashlib
import re

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import FileResponse, JSONResponse
from pydantic import BaseModel, Field

from server.backend import CurrentBackend
from server.jobs import Busy
from server.library import BRANCHES_PER_MINUTE, MAX_BRANCHES, ReplayLibrary
from server.protocol import MAX_HORIZON
from server.replays import ID_PATTERN, Entry

router = APIRouter()


class BranchRequest(BaseModel):
    """``POST /api/replays/{id}/branch``: where to branch and which follower plays on."""

    step: int = Field(ge=0, le=MAX_HORIZON, description="the step the follower takes over at (0..the replay's steps)")
    follower: str = Field(max_length=200, description="one of /api/options' followers")


def file_part(name: str) -> str:
    """A follower's name as part of a file name: readable, and unique (a checkpoint path by its file's stem and
    a short hash of the whole name, so that two ``latest.pt`` in different runs never share a branch)."""
    stem = re.sub(r"[^A-Za-z0-9_.+-]+", "_", name.rsplit("/", 1)[-1].removesuffix(".pt")) or "follower"
    return stem if stem == name else f"{stem}-{hashlib.sha256(name.encode()).hexdigest()[:8]}"


async def busy(request: Request, err: Busy) -> JSONResponse:
    """``Busy`` from any route: 503 with ``Retry-After`` (the app's exception handler)."""
    return JSONResponse({"detail": str(err)}, status_code=503, headers={"Retry-After": str(err.retry_after_s)})


async def usable(library: ReplayLibrary, replay_id: str, cannot: str) -> Entry:
    """The replay with this id (404 if none), or 422 saying it ``cannot`` be used and why."""
    entry = await library.find(replay_id)
    if entry is None:
        raise HTTPException(404, f"no replay with id {replay_id!r}")
    if entry.problem:
        raise HTTPException(422, f"{cannot}: {entry.problem}")
    return entry


@router.get("/api/replays")
async def list_replays(backend: CurrentBackend, source: str | None = None, follower: str | None = None,
                       collection: str | None = None, setting: str | None = None,
                       branch_of: str | None = Query(None, max_length=200),
                       sort: str = Query("created", pattern="^(created|team_score)$"),
                       order: str = Query("desc", pattern="^(asc|desc)$"),
                       offset: int = Query(0, ge=0), limit: int = Query(50, ge=1, le=500)):
    """Recorded and released replays, filtered, sorted and paginated; broken files are listed with their error."""
    items = [e.summary for e in (await backend.replays.entries()).values()]
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


@router.get("/api/replays/{replay_id}", responses={404: {}, 422: {}})
async def get_replay(replay_id: str, backend: CurrentBackend):
    """One replay file, as stored (422 with the problem for a file that does not load)."""
    entry = await usable(backend.replays, replay_id, f"replay {replay_id!r} cannot be used")
    return FileResponse(entry.path, media_type="application/json")


@router.get("/api/replays/{replay_id}/timeline", responses={404: {}, 503: {}})
async def replay_timeline(replay_id: str, backend: CurrentBackend):
    """What the replay player draws: verification, one board per step, belief curves, events, key log."""
    library = backend.replays
    entry = await library.find(replay_id)
    if entry is None:
        raise HTTPException(404, f"no replay with id {replay_id!r}")
    if entry.problem:
        return {"id": replay_id, "verified": False, "problem": entry.problem}
    return FileResponse(await library.jobs.timeline(entry.path, replay_id, entry.mtime, library.max_bytes),
                        media_type="application/json")


@router.get("/api/replays/{replay_id}/people", responses={400: {}, 404: {}, 422: {}, 503: {}})
async def replay_people(replay_id: str, backend: CurrentBackend, follower: str = Query(max_length=200)):
    """Each person in a follower seat of the replay beside ``follower`` (one of /api/options' followers) watching
    their seat: both sides' measures for this game (those ``colorgrid replay rescore`` pools) and the follower's
    beliefs at every step (``colorgrid.replay.human_follower.person_and_follower``); 422 for a game without a person
    in a follower seat."""
    library, choices = backend.replays, backend.settings.follower_choices
    entry = await usable(library, replay_id, f"replay {replay_id!r} cannot be measured")
    if follower not in choices:  # names only: a path from the web would read files
        raise HTTPException(400, f"follower must be one of {list(choices)}, got {follower!r}")
    try:
        out = await library.jobs.people(entry.path, replay_id, entry.mtime, follower, file_part(follower),
                                        library.max_bytes)
    except ValueError as err:
        raise HTTPException(422, f"replay {replay_id!r} cannot be measured: {err}") from None
    return FileResponse(out, media_type="application/json")


@router.get("/api/replays/{replay_id}/export", responses={404: {}, 422: {}, 503: {}})
async def export_replay(replay_id: str, backend: CurrentBackend,
                        format: str = Query("gif", pattern="^(gif|mp4)$")):
    """The replay as a GIF or MP4, made on the server (cached; 503 with Retry-After while busy)."""
    library = backend.replays
    entry = await usable(library, replay_id, "replay cannot be exported")
    try:
        out = await library.jobs.export(entry.path, replay_id, entry.mtime, format, library.max_bytes)
    except ValueError as err:
        raise HTTPException(422, f"replay cannot be exported: {err}") from None
    media = "image/gif" if format == "gif" else "video/mp4"
    return FileResponse(out, media_type=media, filename=f"{replay_id}.{format}")


@router.post("/api/replays/{replay_id}/branch", responses={400: {}, 404: {}, 422: {}, 429: {}, 503: {}})
async def branch_replay(replay_id: str, body: BranchRequest, request: Request, backend: CurrentBackend):
    """The replay continued from ``step`` with another of the server's followers (the leader replays its
    recorded moves), saved under ``branches/`` in the recordings folder and made once: ``{"id": ...}``."""
    library, choices = backend.replays, backend.settings.follower_choices
    entry = await usable(library, replay_id, f"replay {replay_id!r} cannot be branched")
    if body.follower not in choices:  # names only: a path from the web would read files
        raise HTTPException(400, f"follower must be one of {list(choices)}, got {body.follower!r}")
    if replay_id.startswith("branches--"):
        raise HTTPException(422, "a branch cannot be branched again: branch the original replay")
    if entry.summary.get("team", "1:1") != "1:1":
        raise HTTPException(422, f"only 1:1 replays can be branched; this one's team is {entry.summary['team']}")
    if not library.branch_limits.bucket(request.client.host if request.client else "?").allow():
        raise HTTPException(429, f"too many branches from this address: at most {BRANCHES_PER_MINUTE} a minute")
    steps = entry.summary["steps"]
    if not 0 <= body.step <= steps:
        raise HTTPException(422, f"step must be in [0, {steps}] (the replay has {steps} steps), got {body.step}")
    name = f"{replay_id}--branch{body.step}-{file_part(body.follower)}"
    branch_id = f"branches--{name}"
    if not ID_PATTERN.match(branch_id):
        raise HTTPException(422, f"replay {replay_id!r} cannot be branched: its branch's id would be too long")
    out = library.branch_path(name)
    if not out.exists() and library.branches_full():
        raise Busy(f"{MAX_BRANCHES} branches already: remove some from {out.parent}", retry_after_s=60)
    if not out.exists() and (problem := await library.branch(entry, out, body.step, body.follower)) is not None:
        raise HTTPException(422, f"replay {replay_id!r} cannot be branched: {problem}")
    return {"id": branch_id}
