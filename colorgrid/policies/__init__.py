"""Agents behind one interface (``Policy``): scripted baselines and, later, trained checkpoints."""

from __future__ import annotations

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
    """A policy by name: a scripted one from ``SCRIPTED`` or a trained checkpoint file (``*.pt``).

    For a checkpoint holding both agents, ``role`` (``"leader"``/``"follower"``) says which to load.
    """
    if name in SCRIPTED:
        return SCRIPTED[name]()
    if name.endswith(".pt"):
        from train.policy import load_policy  # torch is imported only when a checkpoint is asked for

        return load_policy(name, role=role)
    raise ValueError(f"unknown policy {name!r}; choose one of {sorted(SCRIPTED)} or a checkpoint path ending in .pt")


__all__ = ["SCRIPTED", "AgentInput", "AStarLeader", "BayesConfig", "BayesFollower", "CopyFollower", "IdleFollower",
           "OracleFollower", "Policy", "PolicyOutput", "RandomPolicy", "make_policy"]
