"""The replay file: one JSON document per episode, versioned, checksummed, written atomically.

See ``docs/REPLAY_FORMAT.md`` for every field. Two kinds share the format:
``"actions"`` replays hold the seed and both agents' actions and are re-simulated on
load (the env is deterministic); ``"frames"`` replays hold each step's state
explicitly (imported trajectories) and cannot be re-simulated.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from colorgrid.config import EnvConfig
from colorgrid.enums import Ending, KeyStatus, Role
from colorgrid.files import JSONFileError, atomic_path, read_json
from colorgrid.rng import MAX_SEED

FORMAT_NAME = "colorgrid-replay"
FORMAT_VERSION = 1
SUFFIX = ".replay.json"
SOURCES = ("eval", "train", "play", "import")
MAX_DEPTH = 32
"""Deepest JSON nesting a replay file may have (a real one has about 6 levels)."""


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
    agents: dict  # agent name -> {"policy": ...} ("human" for people; checkpoint sha256), names from config
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
    ended: str = Ending.COMPLETE  # an ``Ending``: "complete", or why it stopped early ("disconnected", ...)
    key_events: list | None = None  # human games: key log (see docs/SERVER_PROTOCOL.md)
    stated_beliefs: dict = field(default_factory=dict)  # a person in a follower seat: name -> [T] color or None
    belief_events: list | None = None  # a person in a follower seat: every statement of a belief, in order
    probes: list | None = None  # a person in a follower seat: every probe asked, with its answer
    created: str = field(default_factory=lambda: datetime.now(UTC).isoformat(timespec="seconds"))
    env_id: str | None = None  # None: the config's (``EnvConfig.env_id``)
    meta: dict = field(default_factory=dict)  # free-form: description, game id, ...

    def __post_init__(self) -> None:
        if self.env_id is None:
            self.env_id = self.config.env_id

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
            for i, name in enumerate(self.config.agent_names):
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
            "agent_names": list(self.config.agent_names), "roles": list(self.config.roles),
            "agents": self.agents, "penalty_coef": self.penalty_coef, "ended": self.ended,
            "steps": {
                "actions": self.actions, "goal": self.goal, "block_reward": self.block_reward,
                "team_reward": self.team_reward, "picked_color": self.picked_color,
                "goal_switched": self.goal_switched, "goal_probs": self.goal_probs,
                "state_hash": self.state_hashes,
            },
            "frames": self.frames, "final": self.final(), "key_events": self.key_events, "meta": self.meta,
        }
        if self.stated_beliefs:  # a person in a follower seat (files without one are as they always were)
            body["steps"]["stated_belief"] = self.stated_beliefs
            body.update(belief_events=self.belief_events or [], probes=self.probes or [])
        body["checksum"] = checksum(body)
        return body

    @classmethod
    def from_document(cls, doc: Any, path=None) -> Replay:
        """A replay from a parsed file; a document that is not a valid replay raises ``ReplayError``."""
        if not isinstance(doc, dict) or doc.get("format") != FORMAT_NAME:
            raise ReplayError(path, f"not a ColorGrid replay (expected \"format\": \"{FORMAT_NAME}\")")
        version = doc.get("format_version")
        if not _is_int(version):
            raise ReplayError(path, "format_version is missing or not an integer")
        if version > FORMAT_VERSION:
            raise ReplayError(path, f"format version {version} is newer than this colorgrid reads "
                                    f"(up to {FORMAT_VERSION}); upgrade colorgrid")
        try:
            expected = checksum({k: v for k, v in doc.items() if k != "checksum"})
        except (TypeError, ValueError, RecursionError) as err:  # a document built in code, not parsed from a file
            raise ReplayError(path, f"cannot be checksummed as JSON: {err}") from None
        if doc.get("checksum") != expected:
            raise ReplayError(path, "checksum mismatch: the file was changed or corrupted after it was written")
        _check_field_types(doc, _DOCUMENT_FIELDS, "", path)
        steps = doc["steps"]
        _check_field_types(steps, _STEP_FIELDS, "steps.", path)
        try:
            config = EnvConfig.from_dict(doc["config"])
        except ValueError as err:
            raise ReplayError(path, f"invalid config: {err}") from None
        replay = cls(
            config=config, seed=doc["seed"], source=doc["source"], agents=doc["agents"],
            actions=steps["actions"], goal=steps["goal"], block_reward=steps["block_reward"],
            team_reward=steps["team_reward"], picked_color=steps["picked_color"],
            goal_switched=steps["goal_switched"], goal_probs=steps.get("goal_probs") or {},
            state_hashes=steps["state_hash"], frames=doc.get("frames"), penalty_coef=doc["penalty_coef"],
            ended=doc["ended"], key_events=doc.get("key_events"), created=doc["created"],
            env_id=doc["env_id"], meta=doc.get("meta") or {}, stated_beliefs=steps.get("stated_belief") or {},
            belief_events=doc.get("belief_events"), probes=doc.get("probes"),
        )
        if doc.get("kind", replay.kind) != replay.kind:
            raise ReplayError(path, f"kind is {doc['kind']!r}, but steps.actions says {replay.kind!r}")
        for name, expected in (("agent_names", config.agent_names), ("roles", config.roles)):
            if name in doc and doc[name] != list(expected):  # files from before teams have neither: the config tells
                raise ReplayError(path, f"{name} is {doc[name]!r}, but the config's team has {list(expected)}")
        replay.validate(path)
        return replay

    def validate(self, path=None) -> None:
        """Check types, shapes and values; raises ``ReplayError`` naming the first problem."""
        T, cfg = self.num_steps, self.config
        A, C, cells = cfg.num_agents, cfg.num_colors, cfg.height * cfg.width

        def require(ok: bool, problem: str) -> None:
            if not ok:
                raise ReplayError(path, problem)

        def rows(value, width: int, element) -> bool:  # a [T][width] list of lists whose entries pass `element`
            return all(isinstance(r, list) and len(r) == width and all(element(x) for x in r) for r in value)

        require(self.env_id == cfg.env_id, f"env_id {self.env_id!r} is not {cfg.env_id!r}, which this colorgrid "
                                           f"simulates for a team of {cfg.num_leaders} leader(s) and "
                                           f"{cfg.num_followers} follower(s)")
        require(self.source in SOURCES, f"source {self.source!r} is not one of {list(SOURCES)}")
        require(self.ended in set(Ending), f"ended {self.ended!r} is not one of {[e.value for e in Ending]}")
        require(0 < T <= cfg.horizon, f"episode has {T} steps; expected 1..horizon ({cfg.horizon})")
        require(all(_is_int(g) and 0 <= g < C for g in self.goal), f"steps.goal must hold colors in [0, {C})")
        require(_is_real(self.penalty_coef) and self.penalty_coef >= 0,
                f"penalty_coef must be a non-negative number, got {self.penalty_coef!r}")
        require(all(isinstance(entry, dict) for entry in self.agents.values()),
                "agents must map each agent name to an object (its policy description)")
        columns = ("actions", "block_reward", "team_reward", "picked_color", "goal_switched")
        if self.kind == "actions":
            require(_is_int(self.seed) and 0 <= self.seed <= MAX_SEED,
                    f"an actions replay needs an integer seed in [0, 2**63 - 1], got {self.seed!r}")
            for name in columns:
                value = getattr(self, name)
                require(isinstance(value, list) and len(value) == T,
                        f"steps.{name} must be a list of {T} entries (one per step)")
            require(rows(self.actions, A, lambda x: _is_int(x) and 0 <= x < cfg.num_actions),
                    f"steps.actions must be [T][{A}] integers in [0, {cfg.num_actions})")
            require(self.state_hashes is None or (len(self.state_hashes) == T + 1
                                                  and all(isinstance(h, str) for h in self.state_hashes)),
                    f"steps.state_hash must have {T + 1} entries (T + 1), each a string")
        else:
            frames = self.frames
            require(self.seed is None or _is_int(self.seed), f"seed must be an integer or null, got {self.seed!r}")
            require(isinstance(frames, dict) and all(isinstance(frames.get(k), list) and len(frames[k]) == T + 1
                                                     for k in ("agent_cell", "blocks", "goal")),
                    f"a frames replay needs frames.agent_cell, frames.blocks and frames.goal with {T + 1} entries")
            require(rows(frames["agent_cell"], A, lambda x: _is_int(x) and 0 <= x < cells),
                    f"frames.agent_cell must be [T+1][{A}] cells in [0, {cells})")
            digits = set(".") | {str(k) for k in range(C)}
            require(all(isinstance(b, str) and len(b) == cells and set(b) <= digits for b in frames["blocks"]),
                    f"frames.blocks must be strings of {cells} characters, each '.' or a color digit below {C}")
            require(all(_is_int(g) and 0 <= g < C for g in frames["goal"]), f"frames.goal must hold colors in [0, {C})")
            per_color = cfg.blocks_per_color  # a state numbers its blocks color by color (EnvState.block_colors)
            wrong = next(((t, k, b.count(str(k))) for t, b in enumerate(frames["blocks"]) for k in range(C)
                          if b.count(str(k)) != per_color), None)
            require(wrong is None, "" if wrong is None else
                    f"frames.blocks[{wrong[0]}] holds {wrong[2]} {cfg.color_names[wrong[1]]} blocks, but the config's "
                    f"block_density {cfg.block_density:g} gives {per_color} of each color")
            present = [name for name in columns[1:4] if getattr(self, name) is not None]
            require(len(present) in (0, 3), "steps.block_reward, team_reward and picked_color come together "
                                            "(all three or none)")
            for name in columns[1:]:
                value = getattr(self, name)
                require(value is None or len(value) == T, f"steps.{name} must be null or a list of {T} entries")
        if self.block_reward is not None:
            require(rows(self.block_reward, A, _is_real), f"steps.block_reward must be [T][{A}] numbers")
            require(all(_is_real(r) for r in self.team_reward), "steps.team_reward must be [T] numbers")
            require(rows(self.picked_color, A, lambda x: _is_int(x) and -1 <= x < C),
                    f"steps.picked_color must be [T][{A}] integers in [-1, {C})")
        if self.goal_switched is not None:
            require(all(isinstance(s, bool) for s in self.goal_switched), "steps.goal_switched must be [T] booleans")
        for name, probs in self.goal_probs.items():
            require(name in cfg.agent_names and probs is not None, f"steps.goal_probs has an unknown agent {name!r}")
            require(isinstance(probs, list) and len(probs) == T and rows(probs, C, _is_real),
                    f"steps.goal_probs.{name} must be [{T}][{C}] numbers")
        if self.key_events is not None:
            require(all(isinstance(k, dict) and _is_real(k.get("t_server", 0)) for k in self.key_events),
                    "key_events must be a list of objects (t_server, when present, a number)")
            require(all(k.get("status", KeyStatus.APPLIED) in set(KeyStatus) for k in self.key_events),
                    f"key_events: a key's status must be one of {[s.value for s in KeyStatus]}")
        for name, stated in self.stated_beliefs.items():
            require(name in cfg.agent_names and cfg.roles[cfg.agent_names.index(name)] == Role.FOLLOWER,
                    f"steps.stated_belief has {name!r}, which is not a follower of the config's team")
            require(isinstance(stated, list) and len(stated) == T
                    and all(c is None or (_is_int(c) and 0 <= c < C) for c in stated),
                    f"steps.stated_belief.{name} must be [{T}] colors in [0, {C}) or null")
        for name in ("belief_events", "probes"):
            entries = getattr(self, name)
            require(entries is None or (isinstance(entries, list) and all(isinstance(e, dict) for e in entries)),
                    f"{name} must be a list of objects")
        for probe in self.probes or []:
            color, confidence = probe.get("color"), probe.get("confidence")
            require((color is None or (_is_int(color) and 0 <= color < C))
                    and (confidence is None or (_is_real(confidence) and 0 <= confidence <= 1)),
                    f"probes: a probe's color must be in [0, {C}) and its confidence in [0, 1], or null")
        sent = self.meta.get("state_sent_ms")
        require(sent is None or (isinstance(sent, list) and all(_is_real(x) for x in sent)),
                "meta.state_sent_ms must be a list of numbers")


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value) -> bool:
    """A JSON number a float can hold (parsing already refused NaN and Infinity; this refuses huge integers)."""
    if isinstance(value, float):
        return math.isfinite(value)
    return _is_int(value) and abs(value) <= 2**53


_OBJECT, _LIST, _STRING, _NUMBER, _INTEGER = "an object", "a list", "a string", "a number", "an integer"
_DOCUMENT_FIELDS = {  # field: (what it must be, may it be null, may it be absent)
    "env_id": (_STRING, False, False), "config": (_OBJECT, False, False), "seed": (_INTEGER, True, False),
    "source": (_STRING, False, False), "created": (_STRING, False, False), "agents": (_OBJECT, False, False),
    "penalty_coef": (_NUMBER, False, False), "ended": (_STRING, False, False), "steps": (_OBJECT, False, False),
    "kind": (_STRING, False, True), "frames": (_OBJECT, True, True), "key_events": (_LIST, True, True),
    "meta": (_OBJECT, True, True), "agent_names": (_LIST, False, True), "roles": (_LIST, False, True),
    "belief_events": (_LIST, True, True), "probes": (_LIST, True, True),
}
_STEP_FIELDS = {
    "actions": (_LIST, True, False), "goal": (_LIST, False, False), "block_reward": (_LIST, True, False),
    "team_reward": (_LIST, True, False), "picked_color": (_LIST, True, False), "goal_switched": (_LIST, True, False),
    "state_hash": (_LIST, True, False), "goal_probs": (_OBJECT, True, True), "stated_belief": (_OBJECT, True, True),
}
_CHECKS = {_OBJECT: lambda v: isinstance(v, dict), _LIST: lambda v: isinstance(v, list),
           _STRING: lambda v: isinstance(v, str), _NUMBER: _is_real, _INTEGER: _is_int}


def _check_field_types(doc: dict, fields: dict, prefix: str, path) -> None:
    """Each field present (or absent only where allowed) with the JSON type the format gives it."""
    for name, (what, nullable, optional) in fields.items():
        if name not in doc:
            if optional:
                continue
            raise ReplayError(path, f"required field {prefix + name!r} is missing")
        value = doc[name]
        if not (_CHECKS[what](value) or (nullable and value is None)):
            shown = repr(value) if isinstance(value, (int, float, str, bool)) or value is None else type(value).__name__
            raise ReplayError(path, f"{prefix}{name} must be {what}{' or null' if nullable else ''}, "
                                    f"got {shown[:60]}")


def checksum(body: dict) -> str:
    """sha256 of the canonical JSON of everything but the checksum itself."""
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return "sha256:" + hashlib.sha256(canonical.encode()).hexdigest()


def save(replay: Replay, path: str | os.PathLike) -> Path:
    """Write atomically: a temporary file in the same folder, flushed and fsynced, then renamed into place."""
    data = json.dumps(replay.to_document(), separators=(",", ":"), allow_nan=False).encode()
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    return Path(path)


def load(path: str | os.PathLike, max_bytes: int | None = None) -> Replay:
    """Read and check a replay file; every problem raises ``ReplayError`` naming the file.

    Only regular files are read; with ``max_bytes`` a larger file is refused before it is read.
    """
    try:
        doc = read_json(path, max_bytes=max_bytes, max_depth=MAX_DEPTH)
    except JSONFileError as err:
        raise ReplayError(path, err.problem) from None
    return Replay.from_document(doc, path)


def describe_agent(policy_description: dict, checkpoint: str | None = None) -> dict:
    """An ``agents`` entry; with a checkpoint (given, or named by the description), its hash pins the weights, and so
    does the hash of every checkpoint named inside it (a person leader's ``base``, a population's ``members``)."""
    out = pin_checkpoints(policy_description)
    checkpoint = checkpoint or out.get("checkpoint")
    if checkpoint is not None:
        out["checkpoint_sha256"] = file_sha256(checkpoint)
    return out


def pin_checkpoints(description: dict | list | object) -> dict | list | object:
    """``description`` with ``checkpoint_sha256`` beside each ``checkpoint`` it holds, at any depth (a file that
    cannot be read raises ``OSError``)."""
    if isinstance(description, list):
        return [pin_checkpoints(v) for v in description]
    if not isinstance(description, dict):
        return description
    out = {k: pin_checkpoints(v) for k, v in description.items()}
    if isinstance(out.get("checkpoint"), str) and "checkpoint_sha256" not in out:
        out["checkpoint_sha256"] = file_sha256(out["checkpoint"])
    return out


_SHA256: dict[tuple, str] = {}


def file_sha256(path: str | os.PathLike) -> str:
    """The file's sha256, computed once per file version (a server records it with every game)."""
    stat = os.stat(path)
    key = (os.path.abspath(path), stat.st_mtime_ns, stat.st_size)
    if key not in _SHA256:
        _SHA256[key] = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return _SHA256[key]


__all__ = ["FORMAT_VERSION", "SUFFIX", "Replay", "ReplayError", "describe_agent", "load", "pin_checkpoints", "save"]
