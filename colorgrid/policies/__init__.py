"""Agents behind one interface (``Policy``): scripted baselines, and policies other packages register."""

from __future__ import annotations

from colorgrid.policies import registry
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.bayes import BayesConfig, BayesFollower
from colorgrid.policies.scripted import AStarLeader, CopyFollower, IdleFollower, OracleFollower, RandomPolicy

SCRIPTED = {
    "random": RandomPolicy,
    "astar": AStarLeader,
    "idle": IdleFollower,
    "copy": CopyFollower,
    "oracle": OracleFollower,
    "bayes": BayesFollower,
}
"""Scripted policies by name. ``astar`` needs the goal (the leader); ``idle`` never collects."""


def make_policy(name: str, role: str | None = None) -> Policy:
    """A policy by name: scripted (``SCRIPTED``), or registered by an installed application (the trainer's
    shipped agents ``ippo`` and ``ippo-leader``, and checkpoint files ``*.pt``).

    For a checkpoint holding both agents, ``role`` (``"leader"``/``"follower"``) says which to load.
    """
    if name in SCRIPTED:
        return SCRIPTED[name]()
    policy = registry.find(name, role)
    if policy is not None:
        return policy
    files = "".join(f" or {what}" for what in registry.registered_files())
    raise ValueError(f"unknown policy {name!r}; choose one of {sorted(SCRIPTED) + registry.registered_names()}{files}")


__all__ = ["SCRIPTED", "AgentInput", "AStarLeader", "BayesConfig", "BayesFollower", "CopyFollower", "IdleFollower",
           "OracleFollower", "Policy", "PolicyOutput", "RandomPolicy", "make_policy"]
