"""Playing: ``/api/options`` (what a new game or room may choose) and the play WebSocket ``/ws/play``, whose
messages (docs/SERVER_PROTOCOL.md) start games, open and join rooms, and carry keys."""

from __future__ import annotations

import asyncio
import logging

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from colorgrid.enums import Role, SeatFit
from colorgrid.presets import PRESETS, env_config
from colorgrid.render import look
from server.backend import CurrentBackend
from server.connection import Connection
from server.followers import follower_info, leader_info
from server.messages import ENDING_WORDS, room_words
from server.protocol import BELIEF_KEYS, KEY_ACTIONS, MAX_HORIZON, ROOM_CODE_LENGTH, SEAT_LABELS, GoalView, Mode, Team
from server.stated import ProbeKind

log = logging.getLogger("colorgrid.server")
router = APIRouter()


@router.get("/api/options")
async def options(backend: CurrentBackend):
    """What a new game may choose (followers, with labels and descriptions in ``follower_info``, AI leaders to lead
    beside in a team of two leaders, in ``leader_info``, presets with their rewards, modes, teams, the horizon's
    limit) and the defaults, plus what the page needs to draw and play: the look of boards, the move keys and each
    ending's words."""
    settings = backend.settings
    presets = {name: env_config(name) for name in sorted(PRESETS)}
    team_followers = {t: backend.hub.team_followers(t) for t in Team}
    team_leaders = {t: backend.hub.team_leaders(t) for t in Team}
    seat_leaders = {t: backend.hub.seat_leaders(t) for t in Team}
    fits = {name: fit for offered in team_leaders.values() for name, fit in offered.items()}
    fits.update({name: SeatFit.DIRECT for offered in seat_leaders.values() for name in offered if name not in fits})
    return {"followers": list(settings.follower_choices), "default_follower": settings.follower,
            "follower_info": [follower_info(name) for name in settings.follower_choices],
            "leader_info": [leader_info(name, fits[name] == SeatFit.PAIR_VIEW) for name in settings.leaders if name in fits],
            "presets": list(presets), "default_preset": settings.preset,
            "preset_settings": {name: {"goal_reward": c.goal_reward, "wrong_penalty": c.wrong_penalty,
                                       "horizon": c.horizon} for name, c in presets.items()},
            "modes": [{"value": m.value, "label": m.label} for m in Mode],
            "teams": [{"value": t.value, "label": t.label, "people": t.people, "ai_followers": t.num_followers,
                       "room": t.room,
                       "followers": team_followers[t], "leaders": list(team_leaders[t]),
                       "seats": [s.value for s in t.seats if s == Role.LEADER or seat_leaders[t]],
                       "follower_seat_leaders": seat_leaders[t]}
                      for t in Team if team_followers[t] or seat_leaders[t]],
            "seats": [{"value": r.value, "label": SEAT_LABELS[r]} for r in Role],
            "goal_views": [{"value": g.value, "label": g.label} for g in GoalView],
            "probe_kinds": [{"value": k.value, "label": k.label} for k in ProbeKind],
            "belief_keys": BELIEF_KEYS,
            "room_code_length": ROOM_CODE_LENGTH, "room_words": room_words(),
            "horizon": {"default": presets[settings.preset].horizon, "max": MAX_HORIZON},
            "keys": KEY_ACTIONS, "look": look(), "endings": {e.value: words for e, words in ENDING_WORDS.items()},
            "tick_hz": settings.tick_hz, "show_belief": settings.show_belief}


@router.websocket("/ws/play")
async def play_socket(ws: WebSocket, backend: CurrentBackend):
    """One browser tab's socket, from the handshake (refused before it is accepted, so the browser sees it fail)
    to its close: its seat then waits for a rejoin, and it leaves the room it waited in."""
    sockets, hub = backend.sockets, backend.hub
    refusal = sockets.refusal(ws)
    if refusal is not None:
        log.warning("refused a play socket: %s", refusal[1])
        await ws.close(refusal[0], refusal[1])
        return
    await ws.accept()
    conn = Connection(ws, hub, sockets.new_games.bucket(ws.client.host if ws.client else "?"))
    sockets.open.add(conn)
    writer = asyncio.create_task(conn.writer())
    try:
        await conn.serve()
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
