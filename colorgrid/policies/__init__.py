"""Agents behind one interface (``Policy``): scripted baselines and, later, trained checkpoints."""

from __future__ import annotations

from pathlib import Path

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


CHECKPOINTS_DIR = Path(__file__).resolve().parents[2] / "checkpoints"
SHIPPED = {"ippo": "follower.pt", "ippo-leader": "leader.pt"}
"""Trained agents that ship in ``checkpoints/``, by name: the IPPO follower and leader (see their model cards)."""


def make_policy(name: str, role: str | None = None) -> Policy:
    """A policy by name: scripted (``SCRIPTED``), shipped (``SHIPPED``) or a checkpoint file (``*.pt``).

    For a checkpoint holding both agents, ``role`` (``"leader"``/``"follower"``) says which to load.
    """
    if name in SCRIPTED:
        return SCRIPTED[name]()
    if name in SHIPPED:
        path = CHECKPOINTS_DIR / SHIPPED[name]
        if not path.is_file():
            raise ValueError(f"the shipped checkpoint for {name!r} is missing: {path} (it is part of the repository)")
        from train.policy import load_policy

        policy = load_policy(path, role=role)
        policy.name = name
        return policy
    if name.endswith(".pt"):
        from train.policy import load_policy  # torch is imported only when a checkpoint is asked for

        return load_policy(name, role=role)
    raise ValueError(f"unknown policy {name!r}; choose one of {sorted(SCRIPTED) + sorted(SHIPPED)} or a checkpoint "
                     f"path ending in .pt")


__all__ = ["SCRIPTED", "SHIPPED", "AgentInput", "AStarLeader", "BayesConfig", "BayesFollower", "CopyFollower", "IdleFollower",
           "OracleFollower", "Policy", "PolicyOutput", "RandomPolicy", "make_policy"]
