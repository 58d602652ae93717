"""Configuration of a ColorGrid environment: one frozen, validated dataclass."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from colorgrid.configkit import (ConfigBase, check_bool, check_choice, check_int, check_number, check_strings, fail,
                                 from_dict, to_dict)
from colorgrid.enums import Role

ENV_ID = "colorgrid_v0"
"""Versioned id of the 1:1 team (one leader, one follower): bumped whenever its dynamics, rewards or
observations change."""
TEAM_ENV_ID = "colorgrid_teams_v0"
"""Versioned id of every other team shape (``num_leaders`` or ``num_followers`` above 1)."""

ROLES = tuple(Role)
"""The two roles (``Role``): a leader knows the goal, a follower (in the asymmetric setting) does not."""
AGENTS = ("leader", "follower")
"""The 1:1 team's agent names, in the order moves and pickups resolve (leader first).
Other team shapes name theirs ``leader_0, leader_1, ..., follower_0, ...`` (``EnvConfig.agent_names``)."""
LEADER, FOLLOWER = 0, 1
"""The 1:1 team's agents' indices in ``AGENTS`` (and in every ``[..., A]`` array). In any team the first
leader is index 0; the followers start at ``num_leaders`` (``EnvConfig.followers``)."""
SYMBOLS = ("L", "F")
"""One letter per agent of the 1:1 team, as boards in text and pictures mark them
(other teams: ``L1, L2, ..., F1, ...``, ``EnvConfig.symbols``)."""
MAX_PER_ROLE = 8
"""The most leaders, and the most followers, a team may have."""

COLOR_NAMES = ("red", "green", "blue", "orange", "purple", "cyan", "brown", "pink")
REWARD_MODES = ("shared", "individual")
PAPER_SWITCH_PROB = 2.0 / 3.0 * 1.0 / 32.0


@dataclass(frozen=True)
class EnvConfig(ConfigBase):
    """Every knob of the ColorGrid rules (see ``docs/ENV_CARD.md``).

    Invalid values raise ``ValueError`` naming the field, the value and what is
    allowed. Use ``dataclasses.replace`` or :meth:`replace` to derive variants.
    """

    ERROR_STYLE = "EnvConfig.{name} must be {allowed}, got {value!r}"
    CONFIG_NAME = "EnvConfig"

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
    num_leaders: int = 1
    """Leaders in the team (1..8). Every leader knows the goal; agents ``0 .. num_leaders - 1``."""
    num_followers: int = 1
    """Followers in the team (1..8); agents ``num_leaders ..``, after every leader."""
    reward_mode: str = "shared"
    """``"shared"``: each agent gets the team's block reward; ``"individual"``: its own only."""
    horizon: int = 128
    """Steps per episode; then every agent is truncated."""
    hemispheres: bool = False
    """Confine the leaders to the left half and the followers to the right half of the columns."""
    allow_stay: bool = False
    """Add action 4, ``stay`` (action space Discrete(5) instead of Discrete(4))."""
    distance_penalty: float = 0.0
    """Shaping (0 = off): an agent within ``distance_threshold`` of the other gets ``-distance_penalty``."""
    distance_threshold: int = 10
    """Manhattan distance at or below which the distance penalty applies."""
    distance_penalty_agents: tuple[str, ...] = ("follower",)
    """Which agents the distance penalty applies to: roles (``"leader"``, ``"follower"``: every agent of
    the role) or agent names (``agent_names``)."""
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
    def one_to_one(self) -> bool:
        """One leader and one follower: the paper's team, named ``leader`` and ``follower``."""
        return self.num_leaders == 1 and self.num_followers == 1

    @property
    def team(self) -> str:
        """The team's shape as ``"L:F"`` (``"1:1"``, ``"2:1"``, ...), as the CLI, the server and replay lists
        write it."""
        return f"{self.num_leaders}:{self.num_followers}"

    @property
    def env_id(self) -> str:
        """``ENV_ID`` for the 1:1 team, ``TEAM_ENV_ID`` for every other shape."""
        return ENV_ID if self.one_to_one else TEAM_ENV_ID

    @property
    def roles(self) -> tuple[Role, ...]:
        """Each agent's role (``Role``), in index order: the leaders, then the followers."""
        return (Role.LEADER,) * self.num_leaders + (Role.FOLLOWER,) * self.num_followers

    @property
    def leaders(self) -> range:
        """The leaders' agent indices."""
        return range(self.num_leaders)

    @property
    def followers(self) -> range:
        """The followers' agent indices."""
        return range(self.num_leaders, self.num_agents)

    @property
    def agent_names(self) -> tuple[str, ...]:
        """The agents, in index order: ``AGENTS`` for 1:1, else ``leader_0, ..., follower_0, ...``."""
        if self.one_to_one:
            return AGENTS
        return (tuple(f"leader_{i}" for i in range(self.num_leaders))
                + tuple(f"follower_{i}" for i in range(self.num_followers)))

    @property
    def symbols(self) -> tuple[str, ...]:
        """Each agent's label on boards and pictures: ``SYMBOLS`` for 1:1, else ``L1, L2, ..., F1, ...``."""
        if self.one_to_one:
            return SYMBOLS
        return (tuple(f"L{i + 1}" for i in range(self.num_leaders))
                + tuple(f"F{i + 1}" for i in range(self.num_followers)))

    @property
    def sees_goal(self) -> tuple[bool, ...]:
        """Which agents' goal information shows the goal: every leader always, a follower only when the
        setting is symmetric (the rule is this property; the env and its kernel read it)."""
        return tuple(role == Role.LEADER or not self.asymmetric for role in self.roles)

    @property
    def num_agents(self) -> int:
        return self.num_leaders + self.num_followers

    def index(self, name: str) -> int:
        """The agent index of ``name`` (one of ``agent_names``); an error lists the names."""
        try:
            return self.agent_names.index(name)
        except ValueError:
            raise ValueError(f"no agent {name!r} in this team; its agents are {list(self.agent_names)}") from None

    def penalised(self, agent: int) -> bool:
        """Whether the distance penalty applies to ``agent`` (named, or its role named, in
        ``distance_penalty_agents``)."""
        names = self.distance_penalty_agents
        return self.agent_names[agent] in names or self.roles[agent] in names

    @property
    def num_actions(self) -> int:
        return 5 if self.allow_stay else 4

    @property
    def num_planes(self) -> int:
        """Observation planes: one per color, then one per agent in index order (1:1: leader, follower)."""
        return self.num_colors + self.num_agents

    @property
    def color_names(self) -> tuple[str, ...]:
        return COLOR_NAMES[: self.num_colors]

    # Conversions ----------------------------------------------------------
    def replace(self, **changes: Any) -> "EnvConfig":
        """A copy with ``changes`` applied (validated; unknown names are an error)."""
        return EnvConfig.from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, Any]:
        """Plain data. The 1:1 team leaves out ``num_leaders`` and ``num_followers`` (both 1, the defaults), so
        that 1:1 replays, checkpoints and run configs read exactly as they did before teams existed."""
        data = to_dict(self)
        if self.one_to_one:
            del data["num_leaders"], data["num_followers"]
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "EnvConfig":
        """Build from a plain dict (e.g. JSON); unknown keys raise ``ValueError`` listing allowed ones."""
        return from_dict(cls, data)


def _real(low: float, high: float = math.inf):
    return lambda v: low <= v <= high


MAGNITUDE = "a finite non-negative magnitude (the sign is applied by the rules)"


def _validate(cfg: EnvConfig) -> None:
    check_int(cfg, "height", 4, 1024)
    check_int(cfg, "width", 4, 1024)
    check_int(cfg, "num_colors", 2, len(COLOR_NAMES))
    check_number(cfg, "block_density", "a number in (0, 1)", _real(0.0, 1.0))
    for name in ("goal_reward", "wrong_penalty", "penalty_coef", "distance_penalty", "potential_scale"):
        check_number(cfg, name, MAGNITUDE, _real(0.0))
    check_number(cfg, "switch_prob", "a number in [0, 1]", _real(0.0, 1.0))
    check_int(cfg, "horizon", 1, 1_000_000)
    check_int(cfg, "distance_threshold", 0, 2048)
    for name in ("asymmetric", "hemispheres", "allow_stay", "potential_shaping"):
        check_bool(cfg, name, "a bool (True or False)")
    check_int(cfg, "num_leaders", 1, MAX_PER_ROLE)
    check_int(cfg, "num_followers", 1, MAX_PER_ROLE)
    check_choice(cfg, "reward_mode", REWARD_MODES)
    check_strings(cfg, "distance_penalty_agents", dict.fromkeys(ROLES + cfg.agent_names), distinct=True)
    if cfg.hemispheres and cfg.width % 2:
        fail(cfg, "width", "even when hemispheres=True (two equal halves)")
    if cfg.blocks_per_color < 1:
        fail(cfg, "block_density", f"large enough for at least one block per color on a {cfg.height}x{cfg.width} "
                                   f"grid (>= {cfg.num_colors / (cfg.height * cfg.width):.4g})")
    # Room to place everything and to respawn a collected block: at least one free cell.
    halves = 2 if cfg.hemispheres else 1
    cells = cfg.height * cfg.width // halves
    blocks = -(-cfg.num_blocks // halves)  # the fuller half holds the odd block
    agents_per_half = max(cfg.num_leaders, cfg.num_followers) if halves == 2 else cfg.num_agents
    if blocks + agents_per_half >= cells:
        where = "each half of the grid" if halves == 2 else "the grid"
        fail(cfg, "block_density", f"small enough that {where} ({cells} cells) keeps a free cell after {blocks} "
                                   f"blocks and {agents_per_half} agent(s)")
