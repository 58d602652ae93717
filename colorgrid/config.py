"""Configuration of a ColorGrid environment: one frozen, validated dataclass."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

ENV_ID = "colorgrid_v0"
"""Versioned id: bumped whenever dynamics, rewards or observations change."""

AGENTS = ("leader", "follower")
"""Agent names, in the order moves and pickups resolve (leader first)."""
LEADER, FOLLOWER = 0, 1
"""The agents' indices in ``AGENTS`` (and in every ``[..., A]`` array): the roles, named once."""
SYMBOLS = ("L", "F")
"""One letter per agent, as boards in text and pictures mark them."""

COLOR_NAMES = ("red", "green", "blue", "orange", "purple", "cyan", "brown", "pink")
REWARD_MODES = ("shared", "individual")
PAPER_SWITCH_PROB = 2.0 / 3.0 * 1.0 / 32.0


@dataclass(frozen=True)
class EnvConfig:
    """Every knob of the ColorGrid rules (see ``docs/ENV_CARD.md``).

    Invalid values raise ``ValueError`` naming the field, the value and what is
    allowed. Use ``dataclasses.replace`` or :meth:`replace` to derive variants.
    """

    height: int = 32
    """Grid rows (4..1024)."""
    width: int = 32
    """Grid columns (4..1024; even when ``hemispheres``)."""
    num_colors: int = 3
    """Number of block colors (2..8): red, green, blue, then orange, purple, ..."""
    block_density: float = 0.10
    """Fraction of cells holding blocks; ``floor(H*W*density/num_colors)`` blocks per color."""
    goal_reward: float = 1.0
    """Reward magnitude (>= 0) for collecting a block of the goal color."""
    wrong_penalty: float = 1.0
    """Penalty magnitude (>= 0) for a block of another color; paid as ``-wrong_penalty * penalty_coef``."""
    penalty_coef: float = 1.0
    """Initial penalty coefficient (>= 0); penalty annealing changes it during training."""
    switch_prob: float = PAPER_SWITCH_PROB
    """Per-step probability (0..1) that the goal switches to another color (paper: 2/3 * 1/32)."""
    asymmetric: bool = True
    """If true, the follower's ``goal_info`` is all zeros (the goal is hidden from it)."""
    reward_mode: str = "shared"
    """``"shared"``: each agent gets the team's block reward; ``"individual"``: its own only."""
    horizon: int = 128
    """Steps per episode; then every agent is truncated."""
    hemispheres: bool = False
    """Confine the leader to the left half and the follower to the right half of the columns."""
    allow_stay: bool = False
    """Add action 4, ``stay`` (action space Discrete(5) instead of Discrete(4))."""
    distance_penalty: float = 0.0
    """Shaping (0 = off): an agent within ``distance_threshold`` of the other gets ``-distance_penalty``."""
    distance_threshold: int = 10
    """Manhattan distance at or below which the distance penalty applies."""
    distance_penalty_agents: tuple[str, ...] = ("follower",)
    """Which agents the distance penalty applies to (subset of ``("leader", "follower")``)."""
    potential_shaping: bool = False
    """Shaping: add ``potential_scale * (sum 1/(d+1) over goal blocks - wrong_penalty * sum 1/(d+1) over others)``."""
    potential_scale: float = 0.2
    """Scale (>= 0) of the potential-field term (paper: 0.2)."""

    def __post_init__(self) -> None:
        _validate(self)

    # Derived values -------------------------------------------------------
    @property
    def blocks_per_color(self) -> int:
        return int(math.floor(self.height * self.width * self.block_density / self.num_colors + 1e-9))

    @property
    def num_blocks(self) -> int:
        return self.blocks_per_color * self.num_colors

    @property
    def agent_names(self) -> tuple[str, ...]:
        """The agents, in index order (``AGENTS``)."""
        return AGENTS

    @property
    def sees_goal(self) -> tuple[bool, ...]:
        """Which agents' goal information shows the goal: the leader always, the follower only when the
        setting is symmetric (the rule is this property; the env and its kernel read it)."""
        return tuple(i == LEADER or not self.asymmetric for i in range(len(AGENTS)))

    @property
    def num_agents(self) -> int:
        return len(AGENTS)

    @property
    def num_actions(self) -> int:
        return 5 if self.allow_stay else 4

    @property
    def num_planes(self) -> int:
        """Observation planes: one per color, then leader, then follower."""
        return self.num_colors + self.num_agents

    @property
    def color_names(self) -> tuple[str, ...]:
        return COLOR_NAMES[: self.num_colors]

    # Conversions ----------------------------------------------------------
    def replace(self, **changes: Any) -> "EnvConfig":
        """A copy with ``changes`` applied (validated; unknown names are an error)."""
        return EnvConfig.from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["distance_penalty_agents"] = list(self.distance_penalty_agents)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "EnvConfig":
        """Build from a plain dict (e.g. JSON); unknown keys raise ``ValueError`` listing allowed ones."""
        if not isinstance(data, dict):
            raise ValueError(f"EnvConfig must be built from a dict, got {type(data).__name__}")
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise ValueError(f"unknown EnvConfig field(s) {unknown}; allowed: {names}")
        data = dict(data)
        if isinstance(data.get("distance_penalty_agents"), list):
            data["distance_penalty_agents"] = tuple(data["distance_penalty_agents"])
        return cls(**data)


def _fail(name: str, value: Any, allowed: str) -> None:
    raise ValueError(f"EnvConfig.{name} must be {allowed}, got {value!r}")


def _check_int(cfg: EnvConfig, name: str, lo: int, hi: int) -> None:
    v = getattr(cfg, name)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        _fail(name, v, f"an integer in [{lo}, {hi}]")


def _check_real(cfg: EnvConfig, name: str, lo: float, hi: float = math.inf, what: str = "") -> None:
    v = getattr(cfg, name)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        _fail(name, v, what or (f"a finite number >= {lo:g}" if hi == math.inf else f"a number in [{lo:g}, {hi:g}]"))


def _check_bool(cfg: EnvConfig, name: str) -> None:
    v = getattr(cfg, name)
    if not isinstance(v, bool):
        _fail(name, v, "a bool (True or False)")


def _validate(cfg: EnvConfig) -> None:
    _check_int(cfg, "height", 4, 1024)
    _check_int(cfg, "width", 4, 1024)
    _check_int(cfg, "num_colors", 2, len(COLOR_NAMES))
    _check_real(cfg, "block_density", 0.0, 1.0, "a number in (0, 1)")
    for name in ("goal_reward", "wrong_penalty", "penalty_coef", "distance_penalty", "potential_scale"):
        _check_real(cfg, name, 0.0, what="a finite non-negative magnitude (the sign is applied by the rules)")
    _check_real(cfg, "switch_prob", 0.0, 1.0)
    _check_int(cfg, "horizon", 1, 1_000_000)
    _check_int(cfg, "distance_threshold", 0, 2048)
    for name in ("asymmetric", "hemispheres", "allow_stay", "potential_shaping"):
        _check_bool(cfg, name)
    if cfg.reward_mode not in REWARD_MODES:
        _fail("reward_mode", cfg.reward_mode, f"one of {list(REWARD_MODES)}")
    agents = cfg.distance_penalty_agents
    names_ok = isinstance(agents, tuple) and all(isinstance(a, str) for a in agents)  # strings before set()
    if not names_ok or not set(agents) <= set(AGENTS) or len(set(agents)) != len(agents):
        _fail("distance_penalty_agents", agents, f"a tuple of distinct names from {list(AGENTS)}")
    if cfg.hemispheres and cfg.width % 2:
        _fail("width", cfg.width, "even when hemispheres=True (two equal halves)")
    if cfg.blocks_per_color < 1:
        _fail(
            "block_density",
            cfg.block_density,
            f"large enough for at least one block per color on a {cfg.height}x{cfg.width} grid "
            f"(>= {cfg.num_colors / (cfg.height * cfg.width):.4g})",
        )
    # Room to place everything and to respawn a collected block: at least one free cell.
    halves = 2 if cfg.hemispheres else 1
    cells = cfg.height * cfg.width // halves
    blocks = -(-cfg.num_blocks // halves)  # the fuller half holds the odd block
    agents_per_half = cfg.num_agents // halves
    if blocks + agents_per_half >= cells:
        where = "each half of the grid" if halves == 2 else "the grid"
        _fail(
            "block_density",
            cfg.block_density,
            f"small enough that {where} ({cells} cells) keeps a free cell after {blocks} blocks and "
            f"{agents_per_half} agent(s)",
        )
