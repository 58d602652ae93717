"""The play protocol: JSON messages over the WebSocket ``/ws/play``, validated with pydantic.

Every message is an object with a ``type``. See ``docs/SERVER_PROTOCOL.md``. This module declares what the page
sends; ``server.messages`` what the server sends back.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from colorgrid.enums import GoalView, Role  # GoalView is the protocol's too (a replay records it)
from colorgrid.env import ACTION_NAMES

_KEYS = {"up": ("ArrowUp", "w", "W"), "down": ("ArrowDown", "s", "S"), "left": ("ArrowLeft", "a", "A"),
         "right": ("ArrowRight", "d", "D")}
KEY_ACTIONS = {key: ACTION_NAMES.index(action) for action, keys in _KEYS.items() for key in keys}
"""Keys the leader may press and the action index each one means (up, down, left, right)."""
MAX_HORIZON = 1000
"""The longest game a player may ask for (``NewGame.horizon``)."""
BELIEF_KEYS = {str(color + 1): color for color in range(9)}
"""Keys a person in the follower seat presses to say which color they believe is the goal (``1`` is color 0); a game
takes those of its own colors (``belief_keys``)."""


def belief_keys(num_colors: int) -> dict[str, int]:
    """The belief keys of a game of ``num_colors`` colors: ``{"1": 0, "2": 1, "3": 2}`` for three."""
    return {key: color for key, color in BELIEF_KEYS.items() if color < num_colors}


class Mode(StrEnum):
    """How a game advances: once per move key of the leader, or on the server's clock."""

    TURN = "turn"
    REALTIME = "realtime"

    @property
    def label(self) -> str:
        """How a page names the mode."""
        return {Mode.TURN: "turn-based", Mode.REALTIME: "real time"}[self]


SEAT_LABELS: dict[Role, str] = {Role.LEADER: "you lead (you know the goal)",
                                 Role.FOLLOWER: "you assist: follow an AI leader and work out the goal"}
"""How a page names the seat a person takes, by its role (``Role``): a leader's (they know the goal; the default) or
a follower's, the assistant's seat, beside AI leaders (the goal hidden from them unless a game shows it)."""


class Team(StrEnum):
    """Who plays a game: leaders and followers, as ``"leaders:followers"``. Every leader is a person (a
    scripted leader takes the seat of one who leaves), or one person leads beside AI leaders (``NewGame.leader``);
    every follower is the server's AI follower."""

    ONE_TO_ONE = "1:1"
    TWO_PEOPLE = "2:1"
    TWO_FOLLOWERS = "1:2"

    @property
    def num_leaders(self) -> int:
        return int(self.value.partition(":")[0])

    @property
    def num_followers(self) -> int:
        return int(self.value.partition(":")[2])

    @property
    def people(self) -> int:
        """Seats for people: one per leader."""
        return self.num_leaders

    @property
    def room(self) -> bool:
        """Whether the game needs a room: more than one person, who meet by a code before it starts."""
        return self.people > 1

    @property
    def seats(self) -> tuple[Role, ...]:
        """The seats a person may take: a leader's in every team, and a follower's (the first follower, beside AI
        leaders) in a team of one leader; a team of several leaders is theirs to lead, its follower the AI's."""
        return (Role.LEADER, Role.FOLLOWER) if self.num_leaders == 1 else (Role.LEADER,)

    @property
    def label(self) -> str:
        """How a page names the team."""
        return {Team.ONE_TO_ONE: "one leader, one follower: you and an AI",
                Team.TWO_PEOPLE: "two leaders, one AI follower: you and another person (a room) or an AI leader",
                Team.TWO_FOLLOWERS: "one leader, two followers: you and two AIs"}[self]


class SeatStatus(StrEnum):
    """How a person's seat of a team's game stands, as the other people see it (``seats``)."""

    PLAYING = "playing"
    RECONNECTING = "reconnecting"  # the connection was lost; the game waits for a rejoin (at most the grace)
    LEFT = "left"  # the person left: a scripted leader plays the seat


class RoomSeatStatus(StrEnum):
    """A seat of a waiting room (``room``)."""

    OPEN = "open"
    JOINED = "joined"
    READY = "ready"


class RoomClosedReason(StrEnum):
    """Why a waiting room closed without its game (``room_closed``)."""

    EXPIRED = "expired"  # nobody started its game in time
    SERVER_SHUTDOWN = "server_shutdown"
    FAILED = "failed"  # its game could not start


class RoomErrorCode(StrEnum):
    """The ``error`` codes of a room request that cannot be met (``server.rooms.RoomError``)."""

    BAD_ROOM_CODE = "bad_room_code"
    ROOM_NOT_FOUND = "room_not_found"
    ROOM_FULL = "room_full"
    ROOM_STARTED = "room_started"


ROOM_CODE_ALPHABET = "ABCDEFGHJKMNPQRSTUVWXYZ23456789"
"""Letters and digits of room codes: none that reads like another (no 0/O, 1/I/L)."""
ROOM_CODE_LENGTH = 8
"""Characters in a room code: 31**8 (about 8.5e11) codes, so that guessing one at the per-address rate of
``new_games_per_minute`` would take centuries."""
ROOM_COUNTDOWN_S = 3
"""Seconds between the last person's ``ready`` and the start of a real-time room's game (the pages count down)."""


def normalise_room_code(text: str) -> str | None:
    """A typed or pasted room code as the server writes it (upper case, spaces and dashes dropped), or None
    when it cannot be one."""
    code = text.upper().replace("-", "").replace(" ", "")
    ok = len(code) == ROOM_CODE_LENGTH and all(c in ROOM_CODE_ALPHABET for c in code)
    return code if ok else None


Viewport = tuple[Annotated[int, Field(ge=0, le=100_000)], Annotated[int, Field(ge=0, le=100_000)]]
"""A page's inner width and height in CSS pixels (recorded in the replay)."""


class _Message(BaseModel):
    # NaN and infinities (JSON's NaN/Infinity, or 1e400) are refused: a replay must stay valid JSON
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class StudyRef(_Message):
    """Who plays a study's game: the server picks its settings from the participant's current page."""

    participant: str = Field(max_length=64)
    session: str = Field(max_length=128)


class GameRequest(_Message):
    """A game's choices, declared once with one set of defaults (the protocol's): what a page's ``new_game`` asks
    for, or what an application assigns (a study's condition, ``GameSettings.request``). It travels whole to the hub
    (``GameHub.new_game``), the offer (``Offer.choose``, ``Offer.seat_choice``) and ``make_config``. A choice left
    None is the server's (its default follower, preset and horizon)."""

    follower: str | None = None
    """Every AI follower's kind (default: the server's, or the first offered for the team)."""
    followers: list[str] | None = Field(default=None, min_length=1, max_length=8)
    """Instead of ``follower``: one kind per AI follower, in agent order (``["ippo-1L2F", "bayes-people"]`` in 1:2)."""
    preset: str | None = None
    mode: Mode = Mode.TURN
    horizon: int | None = Field(default=None, ge=1, le=MAX_HORIZON)
    show_belief: bool = True
    team: Team = Team.ONE_TO_ONE
    """A team with one person (``"1:1"``, ``"1:2"``, or ``"2:1"`` with ``leader``); teams of several people meet in
    a room (``create_room``)."""
    leader: str | None = Field(default=None, max_length=1024)
    """In a team of several leaders (``"2:1"``): the AI leader that plays every leader seat but this person's (one
    of ``/api/options``' team ``leaders``); without it the team's people meet in a room. In the follower seat: the AI
    leader in every leader seat (one of the team's ``follower_seat_leaders``; default the first)."""
    seat: Role = Role.LEADER
    """The person's seat: ``leader``, or ``follower`` (the team's first follower seat, beside AI leaders)."""
    goal: GoalView | None = None
    """The follower seat: whether the goal is ``hidden`` from the person (the default) or ``shown``."""
    probes: str | None = Field(default=None, max_length=400)
    """The follower seat: when the game asks which color is the goal (``server.stated.ProbePlan``): ``none`` (the
    default), ``steps:10,40,70`` or ``random:0.05``."""


class NewGame(GameRequest):
    """Start a game (the server answers ``welcome`` then ``state``): the game's choices (``GameRequest``), and who
    plays it."""

    type: Literal["new_game"]
    study: StudyRef | None = None
    viewport: Viewport | None = None
    """The page's inner width and height in CSS pixels (recorded in the replay)."""


class CreateRoom(_Message):
    """Open a room for a team of several people (answered by ``room``; the game starts when every seat is
    taken and ready)."""

    type: Literal["create_room"]
    team: Team = Team.TWO_PEOPLE
    follower: str | None = None
    preset: str | None = None
    mode: Mode = Mode.TURN
    horizon: int | None = Field(default=None, ge=1, le=MAX_HORIZON)
    show_belief: bool = True
    viewport: Viewport | None = None


class JoinRoom(_Message):
    """Take the next free seat of a waiting room."""

    type: Literal["join_room"]
    code: str = Field(max_length=32)
    viewport: Viewport | None = None


class Ready(_Message):
    """Say that this seat is ready to start (``ready: false`` takes it back before the start)."""

    type: Literal["ready"]
    ready: bool = True


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


StrictIndex = Annotated[int, Field(strict=True, ge=-2**31, le=2**31)]
"""A color or a probe's id in what a person states: a JSON integer only (``"2"``, ``true`` or ``2.0`` are refused, not
read as 2 or as green). The game checks the range it allows."""
StrictNumber = Annotated[float, Field(strict=True, ge=-1e15, le=1e15)]
"""A number in what a person states: a JSON number only (``"0.8"`` and ``true`` are refused, not read as 0.8 or 1)."""


class Belief(_Message):
    """A person in the follower seat says which color they believe is the goal (a click on its swatch; the number
    keys send ``key``)."""

    type: Literal["belief"]
    color: StrictIndex
    t_client: StrictNumber = 0.0


class ProbeAnswer(_Message):
    """The answer to a probe (``state.probe``): the color the person believes is the goal now and how sure they are,
    as a probability from chance (1 / colors) to 1."""

    type: Literal["probe_answer"]
    probe: StrictIndex
    color: StrictIndex
    confidence: StrictNumber
    t_client: StrictNumber = 0.0


class PageEvent(_Message):
    """The page lost or got focus, or was hidden or shown (recorded in the game's replay)."""

    type: Literal["page_event"]
    event: Literal["blur", "focus", "visibilitychange"]
    visible: bool | None = None
    t_client: float = Field(default=0.0, ge=-1e15, le=1e15)


class Ping(_Message):
    """Answered at once with ``pong``; a page measures its round trip so."""

    type: Literal["ping"]
    round_trip_ms: Annotated[float, Field(strict=True, ge=0, le=600_000)] | None = None
    """The round trip the page measured for its previous ping, in ms: during a game, told to the hub's listeners (a
    study records the median of a game's, ``[exclusions] round_trip_ms``)."""


class Quit(_Message):
    """End the game now; it is saved. In a game with other people, leave it: a scripted leader plays on in
    this seat. In a waiting room, leave the room."""

    type: Literal["quit"]


ClientModel = Union[NewGame, CreateRoom, JoinRoom, Ready, Rejoin, Key, Belief, ProbeAnswer, PageEvent, Ping, Quit]
"""A message the page sends, as validated."""
ClientMessage = Annotated[ClientModel, Field(discriminator="type")]
CLIENT_TYPES = ("new_game", "create_room", "join_room", "ready", "rejoin", "key", "belief", "probe_answer",
                "page_event", "ping", "quit")
client_message = TypeAdapter(ClientMessage)
