"""The web pages and what they load: the play and replay pages, their files, and the API's documentation pages
(served with local copies of Swagger UI and ReDoc, so that they work offline)."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import fastapi_offline
from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, Response
from fastapi.staticfiles import StaticFiles

from colorgrid.resources import shipped

WEB_DIR = shipped("web")
DOCS_ASSETS = Path(fastapi_offline.__file__).parent / "static"  # Swagger UI 5 and ReDoc, so /docs works offline
REDOC_LOGO = "https://cdn.redoc.ly/redoc/logo-mini.svg"  # ReDoc's footer fetches it; /redoc serves its own copy
EMPTY_SVG = "data:image/svg+xml,%3Csvg xmlns=%27http://www.w3.org/2000/svg%27/%3E"

router = APIRouter(include_in_schema=False)
router.mount("/static", StaticFiles(directory=WEB_DIR), name="static")


@router.get("/")
async def play_page():
    return FileResponse(WEB_DIR / "index.html")


@router.get("/replays")
async def replays_page():
    return FileResponse(WEB_DIR / "replays.html")


@router.get("/replay")
async def replay_page():
    return FileResponse(WEB_DIR / "replay.html")


@router.get("/favicon.ico")
async def favicon():
    return FileResponse(WEB_DIR / "favicon.ico", media_type="image/x-icon")


@cache
def redoc_js() -> bytes:
    """ReDoc's script without the logo its footer draws from a CDN."""
    return (DOCS_ASSETS / "redoc.standalone.js").read_bytes().replace(REDOC_LOGO.encode(), EMPTY_SVG.encode())


@router.get("/docs-assets/redoc.standalone.js")
async def redoc_script():
    return Response(redoc_js(), media_type="text/javascript")


router.mount("/docs-assets", StaticFiles(directory=DOCS_ASSETS), name="docs-assets")


@router.get("/docs")
async def swagger_ui(request: Request):
    app = request.app
    return get_swagger_ui_html(openapi_url=app.openapi_url, title=f"{app.title}: API",
                               swagger_js_url="/docs-assets/swagger-ui-bundle.js",
                               swagger_css_url="/docs-assets/swagger-ui.css", swagger_favicon_url="/favicon.ico")


@router.get("/redoc")
async def redoc(request: Request):
    app = request.app
    return get_redoc_html(openapi_url=app.openapi_url, title=f"{app.title}: API",
                          redoc_js_url="/docs-assets/redoc.standalone.js", redoc_favicon_url="/favicon.ico",
                          with_google_fonts=False)
