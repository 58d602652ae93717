"""``/api/health``: is this process up, how loaded is it, how well does its tick keep time; in a cluster (several
processes behind HAProxy) the same of every backend, and the counts added up."""

from __future__ import annotations

import os
from typing import Literal

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from colorgrid import __version__
from server.backend import Backend, CurrentBackend
from server.cluster.plan import RESTARTS_ENV

router = APIRouter()


def percentile(ordered: list[float], q: float) -> float:
    """The ``q`` quantile of ``ordered`` (sorted), rounded to 0.01; 0 for none."""
    return round(ordered[int(q * (len(ordered) - 1))], 2) if ordered else 0.0


def backend_health(backend: Backend) -> dict:
    """This process: games running, the limit, its inference process, tick statistics (and, in a cluster, its
    name there)."""
    hub, settings = backend.hub, backend.settings
    lateness = sorted(hub.lateness_ms)  # the last 5000 ticks
    named = {"backend": backend.member.name} if backend.member is not None else {}  # its name in a cluster
    restarts = int(os.environ.get(RESTARTS_ENV, "0") or 0)  # started again by its launcher after it died
    return {"status": "ok", "ready": hub.ready, "version": __version__, **named, "pid": os.getpid(),
            "restarts": restarts,
            "games": hub.live_games(),
            "rooms": len(hub.rooms),
            "max_sessions": settings.max_sessions, "connections": len(backend.sockets.open),
            "follower_pools": len(hub.pools.by_key), "tick_hz": settings.tick_hz,
            "inference_pid": hub.inference.pid, "inference_restarts": max(0, hub.inference.generation - 1),
            "inference_failed_starts": hub.inference.failed_starts,
            "tick_lateness_p50_ms": percentile(lateness, 0.5), "tick_lateness_p99_ms": percentile(lateness, 0.99),
            **hub.stats}


@router.get("/api/health")
async def health(backend: CurrentBackend, scope: Literal["cluster", "backend"] = "cluster"):
    """Liveness and load: games running, the limit, tick statistics. In a cluster, ``backends`` adds every backend
    (each one's games, rooms, connections and tick lateness, or why it did not answer) and ``cluster`` the sums.
    ``scope=backend``: this process alone, answered 503 until it is ready (HAProxy's health check)."""
    own = backend_health(backend)
    if scope == "backend":
        return JSONResponse(own, status_code=200 if own["ready"] else 503)
    if backend.member is None:
        return own
    from server.cluster.siblings import cluster_health

    return {**own, **await cluster_health(backend.member, own)}
