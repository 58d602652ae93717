"""Server settings: one frozen, validated dataclass (``colorgrid play`` builds it from flags)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from colorgrid.configkit import ConfigBase, check_bool, check_choice, check_int, check_number, check_strings, fail
from colorgrid.policies import offered_followers, policy_card
from colorgrid.presets import PRESETS
from colorgrid.resources import shipped
from server.followers import is_leader_kind, leader_kinds_allowed


def yardstick_reason(name: str) -> str | None:
    """Why the policy ``name`` may not be chosen as a person's partner, in words: its card says it is a yardstick for
    evaluation (``PolicyCard.yardstick``); None when it may be."""
    card = policy_card(name)
    if card is None or card.yardstick is None:
        return None
    return f"{name.partition(':')[0]} is a yardstick for evaluation: {card.yardstick}"


@dataclass(frozen=True)
class ServerSettings(ConfigBase):
    """What the play server runs with. Invalid values raise ``ValueError`` saying what is allowed.
    ``colorgrid play`` has one flag per field (``server/cli.py``)."""

    ERROR_STYLE: ClassVar[str] = "{name} must be {allowed}, got {value!r}"

    host: str = "127.0.0.1"
    """Interface to listen on (loopback by default)."""
    port: int = 8000
    """TCP port (0 picks a free one)."""
    follower: str = "ippo-shielded"
    """Default follower: the best assistant for people on the held-out population (docs/ASSISTANT_RECIPE.md, "A
    shielded assistant": fewer wrong pickups than ``bayes-people`` beside every held-out leader, and more net pickups
    on average, about +1 beside three of the six leaders and about 0 beside the others; claims declared before the
    data); a policy name or a checkpoint path. Players may pick another
    allowed one. A study names its own (``server.study.config``)."""
    followers: tuple[str, ...] = field(default_factory=offered_followers)
    """Followers a player may choose from (the default is always allowed); each team offers those that play it.
    By default those whose policy asks for a place in the menu (``colorgrid.policies.PolicyCard.menu``)."""
    leaders: tuple[str, ...] = ("astar",)
    """AI leaders a person may lead beside in a team of two leaders (2:1): scripted leaders (``astar``, ``person``
    with its parameters, ``idle``, ``random``), trained leaders by name (``ippo-leader``) or checkpoint path (a
    network trained in 1:1, such as one imported from the paper's code, sees the game as 1:1: itself and the
    follower). Each team offers those that play it; none: people only."""
    preset: str = "default"
    """Default environment preset (see ``colorgrid.presets.PRESETS``)."""
    tick_hz: float = 5.0
    """Real-time mode: world steps per second."""
    replays_dir: Path = Path("recordings")
    """Where every game's replay is written."""
    released_dir: Path = shipped("replays")
    """Released replays listed beside the recorded games (read-only)."""
    max_sessions: int = 100
    """Concurrent games, rooms waiting for their people included; the next player gets a clear 'server full'
    message."""
    rejoin_grace_s: float = 30.0
    """How long a disconnected game waits for its player to rejoin with the token."""
    idle_timeout_s: float = 300.0
    """A person with no key for this long leaves the game: a game of one person is closed and saved, in a game
    of several a scripted leader plays on in their seat."""
    room_wait_s: float = 600.0
    """A room whose game has not started this long after it was opened is closed."""
    inference_deadline_ms: float = 100.0
    """Follower inference budget per tick; a miss falls back to a safe idle move and is recorded."""
    max_message_bytes: int = 2048
    """Larger client messages are refused."""
    max_messages_per_s: float = 40.0
    """Sustained client message rate; bursts up to twice this are allowed, the rest refused."""
    show_belief: bool = True
    """Send the follower's belief to the page (an experiment may turn it off for everyone)."""
    allowed_hosts: tuple[str, ...] = ("127.0.0.1", "localhost", "[::1]")
    """``Host`` headers the server answers (against DNS rebinding); the listening host is always allowed;
    ``"*"`` allows any (behind a proxy that checks it)."""
    allowed_origins: tuple[str, ...] = ()
    """Web origins (``https://study.example.org``) whose pages may open the play WebSocket besides the
    server's own; ``"*"`` allows any. Clients that send no ``Origin`` (not browsers) are not affected."""
    max_connections: int = 400
    """Open play WebSockets; the next one is refused (close code 1013, try again later)."""
    connection_idle_s: float = 60.0
    """A play WebSocket with no game that sends nothing for this long is closed."""
    new_games_per_minute: float = 30.0
    """Games one client address may start per minute (bursts of the same number)."""
    max_replay_mb: float = 50.0
    """Replay files larger than this are listed with an error and never loaded by the server."""
    max_exports: int = 2
    """GIF/MP4 exports made at once; further requests get 503 with Retry-After."""
    export_cache_mb: float = 200.0
    """Exported files kept for repeat downloads (least recently used removed first; all removed at exit)."""
    max_key_log: int = 20_000
    """Key presses recorded per game; later ones still move the leader and are counted in
    ``meta.key_events_dropped``."""
    header_timeout_s: float = 10.0
    """An HTTP request whose headers are not complete this long after it began is closed."""
    first_seed: int = 0
    """The seed of the first game this process opens; each later game gets the next. 0: the clock's seconds at
    start, so games differ from run to run. A fixed seed replays the same boards (demonstrations, pictures); the
    processes of a cluster each count on their own."""

    def __post_init__(self) -> None:
        check_strings(self, "followers", allowed="a tuple of follower names")
        for field_name, names in (("follower", (self.follower,)), ("followers", self.followers)):
            for name in names:
                if isinstance(name, str) and (reason := yardstick_reason(name)) is not None:
                    fail(self, field_name, f"a follower a person may play beside ({reason})", name)
        check_strings(self, "leaders", allowed="a tuple of leader names")
        for name in self.leaders:
            if not is_leader_kind(name):
                fail(self, "leaders", leader_kinds_allowed(), name)
        for name in ("host", "follower"):
            if not isinstance(getattr(self, name), str) or not getattr(self, name):
                fail(self, name, "a non-empty string")
        check_int(self, "port", 0, 65535)
        check_choice(self, "preset", PRESETS, f"one of {sorted(PRESETS)}")
        check_number(self, "tick_hz", "a number in [0.5, 60]", lambda v: 0.5 <= v <= 60)
        for name in ("replays_dir", "released_dir"):
            if not isinstance(getattr(self, name), Path):
                fail(self, name, "a folder (a Path)")
        for name in ("max_sessions", "max_connections", "max_exports", "max_key_log"):
            check_int(self, name, 1, allowed="a positive integer")
        for name in ("rejoin_grace_s", "idle_timeout_s", "room_wait_s", "inference_deadline_ms", "max_messages_per_s",
                     "connection_idle_s", "new_games_per_minute", "max_replay_mb", "export_cache_mb",
                     "header_timeout_s"):
            check_number(self, name, "a finite number > 0", lambda v: v > 0)
        check_int(self, "max_message_bytes", 256, 1 << 20)
        check_int(self, "first_seed", 0, 2**31 - 1, allowed="an integer in [0, 2147483647] (0: from the clock)")
        check_bool(self, "show_belief")
        for name in ("allowed_hosts", "allowed_origins"):
            check_strings(self, name)

    @property
    def follower_choices(self) -> tuple[str, ...]:
        """Followers a player may choose: the default first, then the others allowed."""
        return tuple(dict.fromkeys((self.follower, *self.followers)))

    @property
    def hosts(self) -> list[str]:
        """Every ``Host`` the server answers: the allowed ones and the host it listens on."""
        listen = f"[{self.host}]" if ":" in self.host else self.host
        extra = [] if self.host in ("0.0.0.0", "::") else [listen]
        return list(dict.fromkeys([*self.allowed_hosts, *extra]))
