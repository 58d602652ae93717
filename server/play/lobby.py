"""Waiting rooms: a team of several people meets in a room (its code shared), each marks ready, and the game starts
after a countdown that every page shows; a room nobody starts in time closes."""

from __future__ import annotations

import asyncio
import logging

from colorgrid.enums import Ending
from server.play.live import Client, Live, send_to
from server.play.offer import Offer
from server.play.sessions import Sessions
from server.protocol import ROOM_COUNTDOWN_S, GameRequest, Mode, RoomClosedReason, RoomErrorCode, Team
from server.rooms import Room, RoomError, new_code, parse_code

log = logging.getLogger("colorgrid.server")


class Lobby:
    """The rooms of this process (``Live.rooms``): opened, joined, left, started, closed."""

    def __init__(self, live: Live, offer: Offer, sessions: Sessions, countdown=asyncio.sleep):
        """``countdown(seconds)`` waits out a room's countdown before its game is made (a test may hold it)."""
        self.live, self.offer, self.sessions, self.countdown = live, offer, sessions, countdown

    async def create_room(self, team: Team, follower: str | None, preset: str | None, mode: Mode,
                          horizon: int | None, show_belief: bool, client: Client,
                          client_info: dict | None = None) -> Room:
        """Open a room for ``team`` with ``client`` in its first seat; it counts as a session until its game
        starts or it closes."""
        team, mode = Team(team), Mode(mode)
        if not team.room:
            raise ValueError(f"team {team.value} has one person: start it with new_game (rooms are for teams of "
                             "several people)")
        request = GameRequest(team=team, follower=follower, preset=preset, mode=mode, horizon=horizon)
        chosen, preset, config = self.offer.choose(request)
        self.live.check_capacity()
        room = Room(code=new_code(self.live.rooms), team=team, config=config, followers=chosen, preset=preset,
                    mode=mode, show_belief=show_belief, tick_hz=self.live.settings.tick_hz)
        room.join(client, client_info or {})
        self.live.rooms[room.code] = room
        await self._send_room(room)
        return room

    async def join_room(self, code: str, client: Client, client_info: dict | None = None) -> Room:
        """Seat ``client`` in the room with ``code``; unknown, started and full rooms raise ``RoomError``."""
        code = parse_code(code)
        room = self.live.rooms.get(code)
        if room is None:
            if any(g.room == code for g in self.live.games.values()):
                raise RoomError(RoomErrorCode.ROOM_STARTED, f"the game of room {code} has already started")
            raise RoomError(RoomErrorCode.ROOM_NOT_FOUND, f"no room {code} is waiting (it may have expired or closed)")
        room.join(client, client_info or {})
        await self._send_room(room)
        return room

    def room_of(self, client: Client, room: Room | None) -> Room | None:
        """``room`` if it still waits and ``client`` sits in it, else None."""
        waiting = room is not None and self.live.rooms.get(room.code) is room and room.seat_of(client) is not None
        return room if waiting else None

    async def set_ready(self, room: Room, client: Client, ready: bool = True) -> None:
        """Mark ``client``'s seat ready (or not); once every seat is taken and ready the game starts, after a
        countdown in real time (``ROOM_COUNTDOWN_S``) that every page shows."""
        seat = room.seat_of(client)
        if room.starting_in_s is not None:
            if not ready:
                raise ValueError("the game is starting: it can no longer be delayed")
            return
        room.members[seat].ready = ready
        if room.all_ready:
            room.starting_in_s = ROOM_COUNTDOWN_S if room.mode == Mode.REALTIME else 0
            room.start_task = asyncio.create_task(self._start(room))
        await self._send_room(room)

    async def leave_room(self, room: Room, client: Client) -> None:
        """``client`` leaves a waiting room (quit, or its socket closed); an empty room closes. A countdown
        under way stops (everyone's ``ready`` is cleared)."""
        if self.live.rooms.get(room.code) is not room:
            if room.opening:  # closed while the game was being made: its seat waits for a rejoin
                room.dropped.append(client)
            return
        room.leave(client)
        if room.start_task is not None:
            room.start_task.cancel()
            room.start_task, room.starting_in_s = None, None
            for member in room.members:
                if member is not None:
                    member.ready = False
        if room.empty:
            del self.live.rooms[room.code]
        else:
            await self._send_room(room)

    async def expire(self, now: float) -> None:
        """Close the rooms whose game nobody started within ``room_wait_s`` (``expired``)."""
        wait_s = self.live.settings.room_wait_s
        for room in list(self.live.rooms.values()):
            if room.starting_in_s is None and now - room.created > wait_s:
                await self.close_room(room, RoomClosedReason.EXPIRED, f"nobody started the game within {wait_s:g} s")

    async def close_room(self, room: Room, reason: RoomClosedReason, message: str) -> None:
        """Close ``room`` and tell its people why (``room_closed``)."""
        if self.live.rooms.pop(room.code, None) is None:
            return
        if room.start_task is not None:
            room.start_task.cancel()
        for member in room.members:
            if member is not None:
                member.client.detach()
                await send_to(member.client, room.closed_message(reason, message))

    async def _start(self, room: Room) -> None:
        await self.countdown(room.starting_in_s)
        if self.live.rooms.get(room.code) is not room or not room.all_ready:
            return
        del self.live.rooms[room.code]  # its session passes to the game (no await between: nothing overtakes it)
        room.opening = True
        people = [(m.client, m.client_info) for m in room.members]
        try:
            game = await self.sessions.open_game(room.config, room.mode, room.followers, room.preset,
                                                 room.show_belief, people, tick_hz=room.tick_hz, room=room.code)
        except Exception as err:  # ServerFull while stopping, a follower that does not load
            log.exception("could not start the game of room %s", room.code)
            for client, _ in people:
                client.detach()
                closed = room.closed_message(RoomClosedReason.FAILED, f"the game could not start: {err}")
                await send_to(client, closed)
            return
        finally:
            room.opening = False
        for client, _ in people:
            if client not in room.dropped:
                client.attach(game)
        for client, _ in people:  # its welcome (and rejoin token) went to a closed socket: it can never come back
            seat = game.seat_of(client) if client in room.dropped else None
            if seat is not None:
                await self.sessions.leave(game, seat, Ending.DISCONNECTED)

    async def _send_room(self, room: Room) -> None:
        for seat, member in enumerate(room.members):
            if member is not None:
                await send_to(member.client, room.message(seat))
