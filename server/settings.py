"""Server settings: one frozen, validated dataclass (``colorgrid play`` builds it from flags)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from colorgrid.cli_config import PRESETS

TICK_MODES = ("turn", "realtime")
REPO_ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class ServerSettings:
    """What the play server runs with. Invalid values raise ``ValueError`` saying what is allowed."""

    host: str = "127.0.0.1"
    """Interface to listen on (loopback by default)."""
    port: int = 8000
    """TCP port (0 picks a free one)."""
    follower: str = "ippo"
    """Default follower: a scripted name or a checkpoint path; players may pick another allowed one."""
    followers: tuple[str, ...] = ("ippo", "bayes", "copy", "oracle", "idle", "random")
    """Followers a player may choose from (the default is always allowed)."""
    preset: str = "default"
    """Default environment preset (see ``colorgrid.cli_config.PRESETS``)."""
    tick_hz: float = 5.0
    """Real-time mode: world steps per second."""
    replays_dir: Path = Path("recordings")
    """Where every game's replay is written."""
    released_dir: Path = REPO_ROOT / "replays"
    """Released replays listed beside the recorded games (read-only)."""
    max_sessions: int = 100
    """Concurrent games; the next player gets a clear 'server full' message."""
    rejoin_grace_s: float = 30.0
    """How long a disconnected game waits for its player to rejoin with the token."""
    idle_timeout_s: float = 300.0
    """A game with no key for this long is closed and saved."""
    inference_deadline_ms: float = 100.0
    """Follower inference budget per tick; a miss falls back to a safe idle move and is recorded."""
    max_message_bytes: int = 2048
    """Larger client messages are refused."""
    max_messages_per_s: float = 40.0
    """Sustained client message rate; bursts up to twice this are allowed, the rest refused."""
    show_belief: bool = True
    """Send the follower's belief to the page (an experiment may turn it off for everyone)."""
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.port, int) or not 0 <= self.port <= 65535:
            raise ValueError(f"port must be an integer in [0, 65535], got {self.port!r}")
        if self.preset not in PRESETS:
            raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {self.preset!r}")
        if not 0.5 <= self.tick_hz <= 60:
            raise ValueError(f"tick_hz must be in [0.5, 60], got {self.tick_hz!r}")
        if not isinstance(self.max_sessions, int) or self.max_sessions < 1:
            raise ValueError(f"max_sessions must be a positive integer, got {self.max_sessions!r}")
        for name in ("rejoin_grace_s", "idle_timeout_s", "inference_deadline_ms", "max_messages_per_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if not 256 <= self.max_message_bytes <= 1 << 20:
            raise ValueError(f"max_message_bytes must be in [256, 1048576], got {self.max_message_bytes!r}")
        if self.follower not in self.followers:
            object.__setattr__(self, "followers", (self.follower, *self.followers))
