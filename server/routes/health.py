"""``/api/health``: is this process up, how loaded is it, how well does its tick keep time."""

from __future__ import annotations

from fastapi import APIRouter

from colorgrid import __version__
from server.backend import CurrentBackend

router = APIRouter()


def percentile(ordered: list[float], q: float) -> float:
    """The ``q`` quantile of ``ordered`` (sorted), rounded to 0.01; 0 for none."""
    return round(ordered[int(q * (len(ordered) - 1))], 2) if ordered else 0.0


@router.get("/api/health")
async def health(backend: CurrentBackend):
    """Liveness and load: games running, the limit, tick statistics."""
    hub, settings = backend.hub, backend.settings
    lateness = sorted(hub.lateness_ms)  # the last 5000 ticks
    return {"status": "ok", "ready": hub.ready, "version": __version__, "games": hub.live_games(),
            "rooms": len(hub.rooms),
            "max_sessions": settings.max_sessions, "connections": len(backend.sockets.open),
            "follower_pools": len(hub.pools), "tick_hz": settings.tick_hz,
            "inference_pid": hub.inference.pid, "inference_restarts": max(0, hub.inference.generation - 1),
            "inference_failed_starts": hub.inference.failed_starts,
            "tick_lateness_p50_ms": percentile(lateness, 0.5), "tick_lateness_p99_ms": percentile(lateness, 0.99),
            **hub.stats}
