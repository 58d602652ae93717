"""The replay file: one JSON document per episode, versioned, checksummed, written atomically.

See ``docs/REPLAY_FORMAT.md`` for every field. Two kinds share the format:
``"actions"`` replays hold the seed and both agents' actions and are re-simulated on
load (the env is deterministic); ``"frames"`` replays hold each step's state
explicitly (imported trajectories) and cannot be re-simulated.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from colorgrid.config import AGENTS, ENV_ID, EnvConfig
from colorgrid.files import atomic_path

FORMAT_NAME = "colorgrid-replay"
FORMAT_VERSION = 1
SUFFIX = ".replay.json"
SOURCES = ("eval", "train", "play", "import")
KINDS = ("actions", "frames")


class ReplayError(ValueError):
    """A replay file that cannot be used: names the file and the problem."""

    def __init__(self, path: str | os.PathLike | None, problem: str):
        self.path, self.problem = (str(path) if path is not None else None), problem
        super().__init__(f"{self.path}: {problem}" if self.path else problem)


@dataclass
class Replay:
    """One episode. Per-step lists have one entry per step ``t`` (0..T-1) unless noted."""

    config: EnvConfig
    seed: int | None  # episode seed (actions replays); None for frames replays
    source: str  # "eval" | "train" | "play" | "import"
    agents: dict  # {"leader": {"policy": ...}, "follower": {...}}; "human" for people; checkpoint sha256
    actions: list | None  # [T][A] ints (actions replays)
    goal: list  # [T] goal color when the step's actions were chosen
    block_reward: list | None  # [T][A] unshaped block rewards
    team_reward: list | None  # [T]
    picked_color: list | None  # [T][A], -1 if nothing collected
    goal_switched: list | None  # [T] bool: the goal switched at the end of step t
    goal_probs: dict = field(default_factory=dict)  # agent name -> [T][C] belief when acting
    state_hashes: list | None = None  # [T + 1] hashes of the state before each step and after the last
    frames: dict | None = None  # frames replays: {"agent_cell": [T+1][A], "blocks": [T+1] strings}
    penalty_coef: float = 1.0  # the penalty coefficient in force during the episode
    ended: str = "complete"  # "complete", or why it stopped early ("disconnected", "idle", ...)
    key_events: list | None = None  # human games: key log (see docs/SERVER_PROTOCOL.md)
    created: str = field(default_factory=lambda: datetime.now(timezone.utc).isoformat(timespec="seconds"))
    env_id: str = ENV_ID
    meta: dict = field(default_factory=dict)  # free-form: description, game id, ...

    @property
    def kind(self) -> str:
        return "actions" if self.actions is not None else "frames"

    @property
    def num_steps(self) -> int:
        return len(self.goal)

    def final(self) -> dict:
        """Totals of the episode (what the file's ``final`` field holds)."""
        out: dict[str, Any] = {"length": self.num_steps}
        if self.block_reward is not None:
            for i, name in enumerate(AGENTS):
                out[f"{name}_score"] = round(sum(r[i] for r in self.block_reward), 6)
                out[f"{name}_goal_pickups"] = sum(1 for t, p in enumerate(self.picked_color) if p[i] >= 0
                                                  and p[i] == self.goal[t])
                out[f"{name}_wrong_pickups"] = sum(1 for t, p in enumerate(self.picked_color) if p[i] >= 0
                                                   and p[i] != self.goal[t])
            out["team_score"] = round(sum(self.team_reward), 6)
        return out

    # ------------------------------------------------------------ documents
    def to_document(self) -> dict:
        body = {
            "format": FORMAT_NAME, "format_version": FORMAT_VERSION, "kind": self.kind, "env_id": self.env_id,
            "config": self.config.to_dict(), "seed": self.seed, "source": self.source, "created": self.created,
            "agents": self.agents, "penalty_coef": self.penalty_coef, "ended": self.ended,
            "steps": {
                "actions": self.actions, "goal": self.goal, "block_reward": self.block_reward,
                "team_reward": self.team_reward, "picked_color": self.picked_color,
                "goal_switched": self.goal_switched, "goal_probs": self.goal_probs,
                "state_hash": self.state_hashes,
            },
            "frames": self.frames, "final": self.final(), "key_events": self.key_events, "meta": self.meta,
        }
        body["checksum"] = checksum(body)
        return body

    @classmethod
    def from_document(cls, doc: Any, path=None) -> "Replay":
        if not isinstance(doc, dict) or doc.get("format") != FORMAT_NAME:
            raise ReplayError(path, f"not a ColorGrid replay (expected \"format\": \"{FORMAT_NAME}\")")
        version = doc.get("format_version")
        if not isinstance(version, int):
            raise ReplayError(path, "format_version is missing or not an integer")
        if version > FORMAT_VERSION:
            raise ReplayError(path, f"format version {version} is newer than this colorgrid reads "
                                    f"(up to {FORMAT_VERSION}); upgrade colorgrid")
        if doc.get("checksum") != checksum({k: v for k, v in doc.items() if k != "checksum"}):
            raise ReplayError(path, "checksum mismatch: the file was changed or corrupted after it was written")
        try:
            steps = doc["steps"]
            config = EnvConfig.from_dict(doc["config"])
            replay = cls(
                config=config, seed=doc["seed"], source=doc["source"], agents=doc["agents"],
                actions=steps["actions"], goal=steps["goal"], block_reward=steps["block_reward"],
                team_reward=steps["team_reward"], picked_color=steps["picked_color"],
                goal_switched=steps["goal_switched"], goal_probs=steps.get("goal_probs") or {},
                state_hashes=steps["state_hash"], frames=doc.get("frames"), penalty_coef=doc["penalty_coef"],
                ended=doc["ended"], key_events=doc.get("key_events"), created=doc["created"],
                env_id=doc["env_id"], meta=doc.get("meta") or {},
            )
        except KeyError as err:
            raise ReplayError(path, f"required field {err.args[0]!r} is missing") from None
        except ValueError as err:
            raise ReplayError(path, f"invalid config: {err}") from None
        replay.validate(path)
        return replay

    def validate(self, path=None) -> None:
        """Check shapes and values; raises ``ReplayError`` naming the first problem."""
        T, cfg = self.num_steps, self.config
        if self.env_id != ENV_ID:
            raise ReplayError(path, f"env_id {self.env_id!r} is not {ENV_ID!r}, which this colorgrid simulates")
        if self.source not in SOURCES:
            raise ReplayError(path, f"source {self.source!r} is not one of {list(SOURCES)}")
        if not 0 < T <= cfg.horizon:
            raise ReplayError(path, f"episode has {T} steps; expected 1..horizon ({cfg.horizon})")
        if any(not isinstance(g, int) or not 0 <= g < cfg.num_colors for g in self.goal):
            raise ReplayError(path, f"steps.goal must hold colors in [0, {cfg.num_colors})")
        if self.kind == "actions":
            if not isinstance(self.seed, int) or self.seed < 0:
                raise ReplayError(path, "an actions replay needs a non-negative integer seed")
            for name in ("actions", "block_reward", "team_reward", "picked_color", "goal_switched"):
                value = getattr(self, name)
                if not isinstance(value, list) or len(value) != T:
                    raise ReplayError(path, f"steps.{name} must be a list of {T} entries (one per step)")
            if any(not isinstance(a, list) or len(a) != cfg.num_agents
                   or any(not isinstance(x, int) or not 0 <= x < cfg.num_actions for x in a) for a in self.actions):
                raise ReplayError(path, f"steps.actions must be [T][2] integers in [0, {cfg.num_actions})")
            if self.state_hashes is not None and len(self.state_hashes) != T + 1:
                raise ReplayError(path, f"steps.state_hash must have {T + 1} entries (T + 1)")
        else:
            frames = self.frames
            if not isinstance(frames, dict) or len(frames.get("agent_cell", [])) != T + 1 \
                    or len(frames.get("blocks", [])) != T + 1:
                raise ReplayError(path, f"a frames replay needs frames.agent_cell and frames.blocks with {T + 1} entries")
        for name, probs in self.goal_probs.items():
            if name not in AGENTS or probs is None:
                raise ReplayError(path, f"steps.goal_probs has an unknown agent {name!r}")
            if len(probs) != T or any(len(p) != cfg.num_colors for p in probs):
                raise ReplayError(path, f"steps.goal_probs.{name} must be [{T}][{cfg.num_colors}]")


def checksum(body: dict) -> str:
    """sha256 of the canonical JSON of everything but the checksum itself."""
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return "sha256:" + hashlib.sha256(canonical.encode()).hexdigest()


def save(replay: Replay, path: str | os.PathLike) -> Path:
    """Write atomically: a temporary file in the same folder, flushed and fsynced, then renamed into place."""
    data = json.dumps(replay.to_document(), separators=(",", ":"), allow_nan=False).encode()
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)


def load(path: str | os.PathLike) -> Replay:
    """Read and check a replay file; every problem raises ``ReplayError`` naming the file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise ReplayError(path, "no such file") from None
    except OSError as err:
        raise ReplayError(path, f"cannot be read: {err.strerror}") from None
    try:
        doc = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ReplayError(path, f"not valid JSON (truncated or corrupt?): {err}") from None
    return Replay.from_document(doc, path)


def describe_agent(policy_description: dict, checkpoint: str | None = None) -> dict:
    """An ``agents`` entry; with a checkpoint (given, or named by the description), its hash pins the weights."""
    out = dict(policy_description)
    checkpoint = checkpoint or out.get("checkpoint")
    if checkpoint is not None:
        out["checkpoint_sha256"] = file_sha256(checkpoint)
    return out


_SHA256: dict[tuple, str] = {}


def file_sha256(path: str | os.PathLike) -> str:
    """The file's sha256, computed once per file version (a server records it with every game)."""
    stat = os.stat(path)
    key = (os.path.abspath(path), stat.st_mtime_ns, stat.st_size)
    if key not in _SHA256:
        _SHA256[key] = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return _SHA256[key]


__all__ = ["FORMAT_VERSION", "Replay", "ReplayError", "SUFFIX", "describe_agent", "load", "save"]
