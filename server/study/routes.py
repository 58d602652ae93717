"""The study's HTTP API and pages, added to the play server by ``colorgrid study run``.

Participants: ``/study?PROLIFIC_PID=...`` (the page), ``/api/study/info``, ``join``, ``view`` and
``advance``; their games go over the play WebSocket with ``new_game.study``. The admin:
``/study/admin`` (the page) and ``/api/study/admin/*``, which need ``Authorization: Bearer TOKEN``
with the token printed at start. While a study runs, the free-play page sends visitors to the
study and the replay pages are not served (replays name participants).
"""

from __future__ import annotations

import secrets
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Depends, FastAPI, Header, HTTPException, Request, Response
from fastapi.responses import FileResponse, JSONResponse, RedirectResponse
from pydantic import BaseModel, ConfigDict, Field, StrictBool
from starlette.background import BackgroundTask
from starlette.concurrency import run_in_threadpool
from starlette.requests import HTTPConnection

from server.backend import CurrentBackend
from server.routes.pages import WEB_DIR
from server.study.errors import AnswerProblems, Finished, Invalid, Refused, ScreenedOut
from server.study.service import StudyService

NOT_SERVED = ("/replays", "/replay", "/api/replays")


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Screen(_Body):
    """What the study page measured before consent, for ``[screening]``."""

    touch_only: StrictBool
    """Whether the device has a touch screen and no fine pointer (no mouse or trackpad): a phone or a tablet."""
    viewport: tuple[Annotated[int, Field(strict=True, ge=0, le=100_000)],
                    Annotated[int, Field(strict=True, ge=0, le=100_000)]]
    """The window's ``[width, height]`` in CSS pixels."""
    round_trips_ms: list[Annotated[float, Field(strict=True, ge=0, le=600_000)]] = Field(max_length=50)
    """The round trips of the pings sent over the play socket (``ping`` to ``pong``), in ms."""


class Join(_Body):
    params: dict[str, str] = Field(default_factory=dict, max_length=32)
    """The study link's URL parameters (``PROLIFIC_PID``, ``STUDY_ID``, ``SESSION_ID``, ``pid``)."""
    session: str | None = Field(default=None, max_length=128)
    """The session key this browser got when it joined before, or the one it proposes for its first join (random
    URL-safe text of 32 to 128 characters), so that a join sent again after its answer was lost resumes."""
    screen: Screen | None = None
    """A study with ``[screening]``: what the page measured (a new participant without it is refused)."""


class Who(_Body):
    pid: str = Field(max_length=64)
    session: str = Field(max_length=128)


class Advance(Who):
    step: int = Field(ge=0, le=100_000)
    answers: dict[str, int | str | None] | None = None
    agree: bool = False


def export_zip(study_file: str, db: str, replays_dir: str, out: str) -> str:
    """In a worker process: the study's tables (Parquet and CSV) in one zip file; returns its path."""
    from server.study.config import load_study
    from server.study.export import write_tables

    folder = Path(out).with_suffix("")
    write_tables(load_study(study_file), db, Path(replays_dir), folder)
    archive = shutil.make_archive(str(folder), "zip", folder)
    shutil.rmtree(folder, ignore_errors=True)
    return archive


@dataclass(frozen=True)
class Served:
    """The study this process serves: its service over the store, its file and the admin's token."""

    service: StudyService
    study_file: Path
    admin_token: str


def served(conn: HTTPConnection) -> Served:
    """The study of the app serving this request (``install_routes`` put it there)."""
    return conn.app.state.study


CurrentStudy = Annotated[Served, Depends(served)]
"""A route's parameter type for the study this process serves (a FastAPI dependency)."""


def admin_only(study: CurrentStudy, authorization: Annotated[str | None, Header()] = None) -> None:
    """Let only the admin through: ``Authorization: Bearer TOKEN`` with the token printed when the study started."""
    scheme, _, token = (authorization or "").partition(" ")
    if scheme.lower() != "bearer" or not secrets.compare_digest(token.encode(), study.admin_token.encode()):
        raise HTTPException(401, "the admin pages need the token printed when the study started "
                                 "(Authorization: Bearer TOKEN)", headers={"WWW-Authenticate": "Bearer"})


router = APIRouter(tags=["study"])
admin = APIRouter(prefix="/api/study/admin", tags=["study"], dependencies=[Depends(admin_only)])


def answered(fn, *args):
    """``fn(*args)``, with the service's refusals as the HTTP answers the study page reads."""
    try:
        return fn(*args)
    except Finished as err:  # what the debrief page said, again: the completion code
        raise HTTPException(403, {"message": str(err), "completion_code": err.completion_code,
                                  "redirect_url": err.redirect_url}) from None
    except ScreenedOut as err:  # why, in words, and the study's return code
        raise HTTPException(403, {"message": str(err), "return_code": err.return_code,
                                  "redirect_url": err.redirect_url}) from None
    except Refused as err:
        raise HTTPException(403, str(err)) from None
    except AnswerProblems as err:  # every problem, for the page to show beside each question
        raise HTTPException(422, {"message": f"{len(err.problems)} answer(s) need attention",
                                  "problems": err.problems, "again": err.again}) from None
    except Invalid as err:
        raise HTTPException(409, str(err)) from None


def pinned(view: dict, response: Response) -> dict:
    """A page whose game another process of the cluster runs: its browser's next requests (the socket that
    rejoins the game) go to that process."""
    where = view.get("live", {}).pop("backend", None)
    if where is not None:
        from server.cluster.siblings import pin

        pin(response, where)
    return view


async def study_only(request: Request, call_next):
    """While a study runs, the free-play page sends visitors to the study and the replay pages are not served."""
    path = request.url.path
    if path == "/":
        query = f"?{request.url.query}" if request.url.query else ""
        return RedirectResponse(f"/study{query}", status_code=307)
    if any(path == p or path.startswith(p + "/") for p in NOT_SERVED):
        return JSONResponse({"detail": "not served while a study runs (replays name participants); the "
                                       "admin downloads the data from /study/admin"}, status_code=404)
    return await call_next(request)


@router.get("/study", include_in_schema=False)
async def study_page():
    return FileResponse(WEB_DIR / "study.html")


@router.get("/study/admin", include_in_schema=False)
async def admin_page():
    return FileResponse(WEB_DIR / "study_admin.html")


@router.get("/api/study/info")
async def info(study: CurrentStudy) -> dict:
    """The study's title, which URL parameters carry the participant id, and what the page measures before consent
    (``screening``: the number of pings; null when the study screens no one)."""
    about = study.service.study
    screening = {"pings": about.screening.pings} if about.screening is not None else None
    return {"id": about.id, "title": about.title, "id_params": list(about.id_params), "anonymous": about.anonymous,
            "screening": screening}


@router.post("/api/study/join")
def join(body: Join, request: Request, response: Response, study: CurrentStudy) -> dict:
    """Start, or resume, the participant the link names; answers their session key and current page. Refused:
    403 with a sentence for the participant; one who finished the study, from another browser: ``detail:
    {message, completion_code, redirect_url}``; one screened out (``[screening]``): ``detail: {message, return_code,
    redirect_url}``."""
    service = study.service
    screen = body.screen.model_dump() if body.screen is not None else None
    who = answered(service.join, body.params, body.session, request.headers.get("user-agent", ""), screen)
    return {**who, "view": pinned(answered(service.view, who["pid"], who["session"]), response)}


@router.post("/api/study/view")
def view(body: Who, response: Response, study: CurrentStudy) -> dict:
    """The participant's current page."""
    return pinned(answered(study.service.view, body.pid, body.session), response)


@router.post("/api/study/advance")
def advance(body: Advance, study: CurrentStudy) -> dict:
    """Finish the current page (consent agreed, answers, a game over) and get the next one. Answers that
    cannot be taken answer 422 with ``detail: {message, problems: [{question, prompt, problem}]}``, every
    problem at once; other refusals 409 with a sentence."""
    return answered(study.service.advance, body.pid, body.session, body.step, body.answers, body.agree)


@admin.get("/summary")
async def summary(study: CurrentStudy, backend: CurrentBackend) -> dict:
    """Participants by status and arm, quotas, completion times and live games; behind HAProxy, every
    backend's live games and tick lateness (``backends``) and the live games of them all."""
    live, backends = sum(g.study is not None for g in backend.hub.games.values()), None
    if backend.member is not None:
        from server.cluster.siblings import cluster_health
        from server.routes.health import backend_health

        cluster = await cluster_health(backend.member, backend_health(backend))
        live, backends = cluster["cluster"]["games"], cluster["backends"]
    return {**await run_in_threadpool(study.service.summary, live), "backends": backends}


@admin.get("/export.zip")
async def export(study: CurrentStudy, backend: CurrentBackend):
    """Every table of ``colorgrid study export`` (Parquet and CSV) in one zip file."""
    study_id = study.service.study.id
    out = Path(tempfile.mkdtemp(prefix="colorgrid-study-export-")) / f"{study_id}-data"
    archive = await backend.jobs.run(export_zip, str(study.study_file), study.service.store.address,
                                     str(backend.shared.recordings), str(out))
    return FileResponse(archive, filename=f"{study_id}-data.zip", media_type="application/zip",
                        background=BackgroundTask(shutil.rmtree, str(out.parent), True))


def install_routes(app: FastAPI, served_study: Served) -> None:
    """Serve the study's pages and API from ``app``, and keep the free-play and replay pages from its visitors."""
    app.state.study = served_study
    app.middleware("http")(study_only)
    app.include_router(router)
    app.include_router(admin)
