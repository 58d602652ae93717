"""The team's rules as functions of the roles (``EnvConfig.roles``): where each agent may stand, who it
plays with, and what each has scored. Every module that needs one of these asks here."""

from __future__ import annotations

from colorgrid.config import EnvConfig
from colorgrid.enums import Role
from colorgrid.state import EnvState


def columns(config: EnvConfig, agent: int) -> tuple[int, int]:
    """``(first, stop)``: the columns agent ``agent`` may stand on, ``first <= col < stop``.

    Every column, except in hemisphere mode: the leaders keep to the left half, the followers
    to the right half (the move table, the initial layout and the scripted agents all read this).
    """
    if not config.hemispheres:
        return 0, config.width
    half = config.width // 2
    return (0, half) if config.roles[agent] == Role.LEADER else (half, config.width)


def others(config: EnvConfig, agent: int) -> list[int]:
    """Every agent index but ``agent``, in index order."""
    return [a for a in range(config.num_agents) if a != agent]


def scores(state: EnvState, config: EnvConfig, index: int = 0) -> dict[str, float]:
    """Env ``index``'s scores so far: ``team`` (the sum), then one per agent by name (``agent_names``)."""
    score = state.score[index]
    return {"team": float(score.sum()), **{name: float(score[i]) for i, name in enumerate(config.agent_names)}}
