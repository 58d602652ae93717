"""The play protocol's other half: every message the server sends to the page on ``/ws/play``, as pydantic models.

``server.protocol`` declares what the page sends; this module declares what it gets back. The server builds each
message as its model where it is made (``Game.welcome``, ``Game.state_message``, ``Room.message``, ...) and sends its
``wire`` form; ``server_message`` validates one as it arrived (a test plays real games and validates every message
sent), and ``messages_table`` writes the declaration as docs/SERVER_PROTOCOL.md's table "From the server". Every
model forbids fields it does not declare, so a new field or message type must be declared here before it is built.

``ENDING_WORDS`` says each ending (``colorgrid.enums.Ending``) in a player's words, and ``ROOM_ERROR_WORDS``,
``ROOM_CLOSED_WORDS`` and ``SEAT_WORDS`` each room error, room-closed reason and seat status; ``/api/options`` sends
them and the pages show them, so the pages hold no list of endings or room words of their own.
"""

from __future__ import annotations

import re
import typing
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_validator

from colorgrid.enums import Ending, Role
from server.protocol import GoalView, Mode, RoomClosedReason, RoomErrorCode, RoomSeatStatus, SeatStatus

ENDING_WORDS: dict[Ending, str] = {
    Ending.COMPLETE: "Game over.",
    Ending.IDLE: "The game ended: no key was pressed for a long while.",
    Ending.QUIT: "You ended the game.",
    Ending.LEFT: "You left the game; it goes on with a scripted leader in your place.",
    Ending.DISCONNECTED: "The game ended: the connection was lost for too long.",
    Ending.SERVER_SHUTDOWN: "The server stopped: your game was saved.",
    Ending.STAND_IN_FAILED: "The game ended: a person left and no scripted leader could take their seat. "
                            "It was saved.",
    Ending.SERVER_LOST: "The game was cut short when its server stopped; you will play it again.",
}
"""Each ending as a page says it (``/api/options``' ``endings``)."""
ROOM_ERROR_WORDS: dict[RoomErrorCode, str] = {
    RoomErrorCode.BAD_ROOM_CODE: "That is not a room code: check the link or the code you were sent.",
    RoomErrorCode.ROOM_NOT_FOUND: "No room with that code is waiting: it may have expired. Ask for a new link.",
    RoomErrorCode.ROOM_FULL: "That room is full: everyone it needs has joined.",
    RoomErrorCode.ROOM_STARTED: "That room's game has already started.",
}
"""Each room request's ``error`` code as a page says it (``/api/options``' ``room_words.errors``)."""
ROOM_CLOSED_WORDS: dict[RoomClosedReason, str] = {
    RoomClosedReason.EXPIRED: "The room closed: its game did not start in time. Open a new one.",
    RoomClosedReason.SERVER_SHUTDOWN: "The server is restarting: try again in a minute.",
    RoomClosedReason.FAILED: "The room's game could not start: open a new room.",
}
"""Each reason a ``room_closed`` gives as a page says it (``/api/options``' ``room_words.closed``)."""
SEAT_WORDS: dict[RoomSeatStatus | SeatStatus, str] = {
    RoomSeatStatus.OPEN: "waiting for a person",
    RoomSeatStatus.JOINED: "joined",
    RoomSeatStatus.READY: "ready",
    SeatStatus.PLAYING: "playing",
    SeatStatus.RECONNECTING: "reconnecting...",
    SeatStatus.LEFT: "left: a scripted leader plays on",
}
"""Each status of a room's seat (``room``) and of a team game's seat (``seats``) as a page says it beside the seat
(``/api/options``' ``room_words.seats``)."""


def room_words() -> dict[str, dict[str, str]]:
    """The room's words as ``/api/options`` sends them: ``errors``, ``closed`` and ``seats``, each by its value."""
    return {name: {member.value: words for member, words in table.items()}
            for name, table in (("errors", ROOM_ERROR_WORDS), ("closed", ROOM_CLOSED_WORDS), ("seats", SEAT_WORDS))}

AGENT_NAME = re.compile(r"(leader|follower)(_\d+)?")
"""An agent's name (``colorgrid.config.EnvConfig.agent_names``): ``leader``, ``follower_1``, ..."""


class _Outgoing(BaseModel):
    model_config = ConfigDict(extra="forbid")

    def wire(self) -> dict:
        """The message as it is sent: the fields it was built with (an optional field left out stays out)."""
        return self.model_dump(exclude_unset=True)


# ---------------------------------------------------------------- parts of messages
class LookAgent(_Outgoing):
    """How one agent is drawn."""

    name: str
    role: Role
    symbol: str
    body: str
    ink: str


class Look(_Outgoing):
    """How boards are drawn, as ``#rrggbb`` colors (``colorgrid.render.look``)."""

    palette: list[str]
    floor: str
    grid: str
    agents: list[LookAgent]


class Prediction(_Outgoing):
    """What a page needs to draw its person's own move before the state shows it."""

    moves: dict[str, list[int]]
    columns: list[int]


class SeatView(_Outgoing):
    """A person's seat in a game of a team."""

    agent: str
    symbol: str
    status: SeatStatus


class RoomSeat(_Outgoing):
    """A seat of a waiting room."""

    agent: str
    symbol: str
    status: RoomSeatStatus


class Pickup(_Outgoing):
    """A block an agent collected in the last step."""

    agent: str
    color: int
    goal: bool


class Switch(_Outgoing):
    """The goal switched at the end of the last step."""

    switch: int


class OpenProbe(_Outgoing):
    """The open probe of the follower seat."""

    id: int
    step: int


# ---------------------------------------------------------------- the messages
class Welcome(_Outgoing):
    """A game starts or is taken back (``new_game``, a room's start, ``rejoin``); each person gets their own."""

    type: Literal["welcome"]
    game_id: str
    token: str = Field(description="this person's secret for `rejoin`: each person of a room gets their own")
    mode: Mode
    follower: str = Field(description="the AI followers' kind; `\"KIND0 + KIND1\"` when they differ, `\"none\"` when "
                                      "the person is the only follower")
    preset: str
    tick_hz: float | None = Field(description="steps a second in real time; null turn-based")
    height: int
    width: int
    colors: list[str] = Field(description="the block colors' names")
    horizon: int
    show_belief: bool
    keys: list[str] = Field(description="the move keys")
    look: Look = Field(description="this game's colors and agents, as in `/api/options`")
    next_seq: int = Field(description="the `seq` of this person's next key: 0 in a new game, one above their last key "
                                      "on a `rejoin`")
    prediction: Prediction = Field(description="`moves`: each move key's `[row, col]` change; `columns`: the "
                                               "`[first, stop)` columns the person's agent may stand on")
    team: str = Field(None, description="a team other than 1:1: its shape (`\"2:1\"`)")
    agent: str = Field(None, description="a team other than 1:1, or the follower seat: the agent this person plays "
                                         "(`\"leader_1\"`, `\"follower\"`)")
    seats: list[SeatView] = Field(None, description="a team other than 1:1: the people's seats, as in `seats`")
    room: str | None = Field(None, description="a team other than 1:1: the room's code, or null")
    seat: Role = Field(None, description="the follower seat: `\"follower\"`")
    goal_view: GoalView = Field(None, description="the follower seat: `hidden` or `shown`")
    belief_keys: dict[str, int] = Field(None, description="the follower seat: the keys that state a belief "
                                                          "(`{\"1\": 0, \"2\": 1, \"3\": 2}`)")
    probes: str = Field(None, description="the follower seat: the probe plan, as written")
    confidence_min: float = Field(None, description="the follower seat: 1 / colors, the lowest confidence an answer "
                                                    "may give")
    followers: dict[str, str] = Field(None, description="more than one AI follower: each one's kind by agent name")
    leaders: dict[str, str] = Field(None, description="beside AI leaders: each one's kind by agent name "
                                                      "(`{\"leader_1\": \"astar\"}`)")


class State(_Outgoing):
    """The game after a step (and at its start): sent to every person of the game."""

    model_config = ConfigDict(extra="allow")  # one field per agent, by name: checked below

    type: Literal["state"]
    step: int
    horizon: int
    blocks: str = Field(description="`H*W` characters: `.` or the color's digit")
    goal: int | None = Field(description="the goal color; null in the follower seat with the goal hidden")
    scores: dict[str, float] = Field(description="`team`, then one per agent by name")
    belief: list[float] | None = Field(None, description="1:1: the follower's probabilities, or null when hidden "
                                                         "or not yet formed")
    beliefs: dict[str, list[float] | None] = Field(None, description="a team: one per AI follower by name, each as "
                                                                     "`belief`")
    events: list[Pickup | Switch] = Field(description="the last step's pickups `{agent, color, goal}` and "
                                                      "`{switch: color}` (no switch in the follower seat with the "
                                                      "goal hidden)")
    stated: int | None = Field(None, description="the follower seat: the color the person last said is the goal, or "
                                                 "null")
    probe: OpenProbe | None = Field(None, description="the follower seat: the open probe, `{id, step}`, or null")
    last_applied_seq: int | None | dict[str, int | None] = Field(
        description="the `seq` of the person's last key applied (null: none yet); a team: one per person's agent")

    @model_validator(mode="after")
    def _agent_cells(self) -> State:
        for name, cell in (self.model_extra or {}).items():
            if not AGENT_NAME.fullmatch(name) or not isinstance(cell, int) or isinstance(cell, bool) or cell < 0:
                raise ValueError(f"{name!r} is not declared: a state's extra fields are agent cells "
                                 "(leader, follower_0, ...: row * width + col)")
        return self


class ScoredProbe(_Outgoing):
    """A probe answer beside the goal on screen when it arrived."""

    step: int
    color: int
    confidence: float
    goal: int
    response_ms: float | None


class StatedRecord(_Outgoing):
    """What the person in the follower seat said beside the goal's history, and how well it read the goal."""

    goal: list[int] = Field(description="the goal at each step (when its moves were made)")
    stated: list[int | None] = Field(description="the color the person had said at each step, or null")
    probes: list[ScoredProbe] = Field(description="the answered probes, each with the goal it is scored against")
    steps: int
    stated_steps: int
    accuracy: float | None = Field(description="the share of the stated steps whose stated color was the goal")
    probes_asked: int
    probes_answered: int
    probe_accuracy: float | None


class GameOver(_Outgoing):
    """The game ended (the connection closes after it)."""

    type: Literal["game_over"]
    reason: Ending = Field(description="how it ended (`colorgrid.enums.Ending`; words for each in `/api/options`' "
                                       "`endings`): `left` to a person who left a game others play on, whose "
                                       "`replay_id` is null (the replay is saved when the game ends); never "
                                       "`server_lost`, which only a study's data holds")
    replay_id: str | None
    steps: int
    scores: dict[str, float]
    stated: StatedRecord | None = Field(None, description="the follower seat, once the game is saved: the goal at "
                                                          "each step, the stated color at each step, the answered "
                                                          "probes and their accuracy (`colorgrid.replay."
                                                          "human_follower`'s measures)")


class RoomMessage(_Outgoing):
    """A room opened, someone joined, readied or left it: to each person waiting in it."""

    type: Literal["room"]
    code: str
    link: str = Field(description="`/?room=CODE`, the page's path to share")
    team: str
    mode: Mode
    preset: str
    follower: str
    horizon: int
    seats: list[RoomSeat]
    you: str = Field(description="this tab's agent")
    starting_in_s: int | None = Field(description="null; once everyone is ready, the whole seconds until the game "
                                                    "starts: 3 in real time, 0 turn-based")


class RoomClosed(_Outgoing):
    """A waiting room closed without its game."""

    type: Literal["room_closed"]
    code: str
    reason: RoomClosedReason = Field(description="`failed`: the game could not start")
    message: str


class Seats(_Outgoing):
    """A seat of a team's game changed: to its people."""

    type: Literal["seats"]
    seats: list[SeatView] = Field(description="status `playing`, `reconnecting` or `left` (a scripted leader plays "
                                              "the seat)")


class Error(_Outgoing):
    """A message refused or a problem on the server; the game goes on."""

    type: Literal["error"]
    code: str = Field(description="`invalid_message`, `unknown_type`, `bad_json`, `too_large`, `rate_limited`, "
                                  "`bad_seq`, `bad_key`, `bad_belief`, `bad_probe`, `rejected`, a room's code, "
                                  "`internal`")
    message: str


class Full(_Outgoing):
    """No game could start: the server is full or shutting down."""

    type: Literal["full"]
    message: str


class Replaced(_Outgoing):
    """Another connection rejoined this game; this one no longer controls it."""

    type: Literal["replaced"]
    game_id: str
    message: str


class Pong(_Outgoing):
    """The answer to ``ping``."""

    type: Literal["pong"]
    t_server: float = Field(description="the server's clock, ms")


ServerModel = Union[Welcome, State, GameOver, RoomMessage, RoomClosed, Seats, Error, Full, Replaced, Pong]
"""A message the server sends, as built (``wire`` gives what goes out)."""
ServerMessage = Annotated[ServerModel, Field(discriminator="type")]
SERVER_TYPES = tuple(typing.get_args(m.model_fields["type"].annotation)[0]
                     for m in typing.get_args(typing.get_args(ServerMessage)[0]))
"""Every message type the server sends, in the declaration's order."""
server_message = TypeAdapter(ServerMessage)
"""Validates one message the server sends (``server_message.validate_python(dict)``)."""


# ---------------------------------------------------------------- the documented table
def messages_table() -> str:
    """docs/SERVER_PROTOCOL.md's table of the server's messages: one row per type, its fields in order (``?``: only
    in some games) with what each holds."""
    rows = ["| type | when | fields |", "|---|---|---|"]
    for model in typing.get_args(typing.get_args(ServerMessage)[0]):
        kind = typing.get_args(model.model_fields["type"].annotation)[0]
        fields = []
        for name, info in model.model_fields.items():
            if name == "type":
                continue
            shown = f"`{name}`" + ("" if info.is_required() else "?")
            fields.append(shown + (f" ({info.description})" if info.description else ""))
        if model is State:
            fields.insert(2, "one field per agent, named as in `look.agents` (`leader`, `follower` in 1:1; "
                             "`leader_0`, `follower_1`, ... in a team: its cell, row * width + col)")
        when = " ".join(model.__doc__.split()).replace("``", "`")
        rows.append(f"| `{kind}` | {when} | {', '.join(fields)} |")
    return "\n".join(rows) + "\n"
