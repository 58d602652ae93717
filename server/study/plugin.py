"""How a study plugs into the play server: ``StudySetup`` is the server's plugin (``server.backend.Plugin``), and
``StudyGames`` the hub's game source: a participant's ``new_game`` plays the game their current page assigns."""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from pathlib import Path

from fastapi import FastAPI

from server.backend import Backend
from server.game import Game
from server.play.live import Client
from server.play.source import OpenGame
from server.protocol import NewGame, Team
from server.study.config import Study
from server.study.errors import Invalid, Refused
from server.study.routes import Served, install_routes
from server.study.service import StudyService, study_hash
from server.study.store import StudyStore

STUDY_PAGE = "this server runs a study: games start from the study page"


class StudyGames:
    """The study as the hub's game source: no rooms, no quitting, and each game the one the participant's page
    plays (``StudyService.game_for``)."""

    room_refusal = STUDY_PAGE
    quit_refusal = "a study's game cannot be ended early"

    def __init__(self, service: StudyService):
        self.service = service

    @property
    def elsewhere(self):
        """Where another process of the deployment runs a participant's game (``StudyService.elsewhere``)."""
        return self.service.elsewhere

    @elsewhere.setter
    def elsewhere(self, find) -> None:
        self.service.elsewhere = find

    async def new_game(self, open_game: OpenGame, request: NewGame, client: Client, client_info: dict) -> Game:
        """The game of the participant ``request.study`` names; refusals are ``ValueError``s for the page."""
        if request.study is None:
            raise ValueError(STUDY_PAGE)
        if request.team != Team.ONE_TO_ONE:
            raise ValueError("a study's games are one person with one AI follower (team 1:1); the study file sets "
                             "everything else")
        try:
            game, meta = await asyncio.get_running_loop().run_in_executor(
                None, self.service.game_for, request.study.participant, request.study.session)
        except (Refused, Invalid) as err:
            raise ValueError(str(err)) from None
        return await open_game(game.request(), client, client_info, tick_hz=game.tick_hz, study=meta)

    def game_of(self, key: str) -> Game | None:
        """The live game of participant ``key`` in this process."""
        return self.service.live.get(key)


@dataclass(frozen=True)
class StudySetup:
    """What the play server needs to serve a study: its plugin (picklable, for every process of a cluster)."""

    study: Study
    study_file: Path
    database: str | Path
    """The study's database: an SQLite file, or a URL (``server.study.store.database_url``)."""
    admin_token: str

    @property
    def routing_params(self) -> tuple[str, ...]:
        """The URL parameters that carry the participant id (``Study.id_params``)."""
        return tuple(self.study.id_params)

    def store(self) -> StudyStore:
        """The study's database, opened (created, or brought to the current schema) and checked."""
        return StudyStore(self.database, self.study.id, study_hash(self.study))

    def service(self) -> StudyService:
        """The study's service over its store, opened for this process."""
        store = self.store()
        if store.changed_study:
            logging.getLogger("colorgrid.server").warning(
                "%s was made with another version of %s: participants who started keep their assignment, but "
                "changed pages or conditions apply to everyone from now on", store.name, self.study_file)
        return StudyService(self.study, store)

    def install(self, app: FastAPI, backend: Backend) -> None:
        """Serve the study from ``app``: its pages and API (``server.study.routes``), its games from the hub (the
        study chooses them, and records each as it starts and ends); the store is closed when the process stops."""
        service = self.service()
        backend.hub.source = StudyGames(service)
        backend.hub.listeners.append(service)
        backend.closing.append(service.store.close)
        install_routes(app, Served(service, self.study_file, self.admin_token))
