"""The play protocol: JSON messages over the WebSocket ``/ws/play``, validated with pydantic.

Every message is an object with a ``type``. See ``docs/SERVER_PROTOCOL.md``.
"""

from __future__ import annotations

from enum import Enum
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from colorgrid.env import ACTION_NAMES

_KEYS = {"up": ("ArrowUp", "w", "W"), "down": ("ArrowDown", "s", "S"), "left": ("ArrowLeft", "a", "A"),
         "right": ("ArrowRight", "d", "D")}
KEY_ACTIONS = {key: ACTION_NAMES.index(action) for action, keys in _KEYS.items() for key in keys}
"""Keys the leader may press and the action index each one means (up, down, left, right)."""
MAX_HORIZON = 1000
"""The longest game a player may ask for (``NewGame.horizon``)."""


class Mode(str, Enum):
    """How a game advances: once per move key of the leader, or on the server's clock."""

    TURN = "turn"
    REALTIME = "realtime"

    @property
    def label(self) -> str:
        """How a page names the mode."""
        return {Mode.TURN: "turn-based", Mode.REALTIME: "real time"}[self]


class _Message(BaseModel):
    # NaN and infinities (JSON's NaN/Infinity, or 1e400) are refused: a replay must stay valid JSON
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class StudyRef(_Message):
    """Who plays a study's game: the server picks its settings from the participant's current page."""

    participant: str = Field(max_length=64)
    session: str = Field(max_length=128)


class NewGame(_Message):
    """Start a game (the server answers ``welcome`` then ``state``)."""

    type: Literal["new_game"]
    follower: str | None = None
    preset: str | None = None
    mode: Mode = Mode.TURN
    horizon: int | None = Field(default=None, ge=1, le=MAX_HORIZON)
    show_belief: bool = True
    study: StudyRef | None = None
    viewport: tuple[Annotated[int, Field(ge=0, le=100_000)], Annotated[int, Field(ge=0, le=100_000)]] | None = None
    """The page's inner width and height in CSS pixels (recorded in the replay)."""


class Rejoin(_Message):
    """Take a disconnected game back within the grace period."""

    type: Literal["rejoin"]
    game_id: str = Field(max_length=64)
    token: str = Field(max_length=128)


class Key(_Message):
    """A key press; ``seq`` numbers the page's keys, ``t_client`` is its timestamp in ms."""

    type: Literal["key"]
    key: str = Field(max_length=32)
    seq: int = Field(ge=0, le=2**53)
    t_client: float = Field(default=0.0, ge=-1e15, le=1e15)


class PageEvent(_Message):
    """The page lost or got focus, or was hidden or shown (recorded in the game's replay)."""

    type: Literal["page_event"]
    event: Literal["blur", "focus", "visibilitychange"]
    visible: bool | None = None
    t_client: float = Field(default=0.0, ge=-1e15, le=1e15)


class Ping(_Message):
    type: Literal["ping"]


class Quit(_Message):
    """End the game now; it is saved."""

    type: Literal["quit"]


ClientMessage = Annotated[Union[NewGame, Rejoin, Key, PageEvent, Ping, Quit], Field(discriminator="type")]
CLIENT_TYPES = ("new_game", "rejoin", "key", "page_event", "ping", "quit")
client_message = TypeAdapter(ClientMessage)


def error(code: str, message: str) -> dict:
    """An ``error`` message; the game goes on."""
    return {"type": "error", "code": code, "message": message}
