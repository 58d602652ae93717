"""Populations of policies: named members in a file, split into a training and a held-out part.

A population file (JSON) names its members by policy spec and says which part each is in::

    {"description": "...",
     "training": {"astar": "astar", "slips": "person:slip=0.1", ...},
     "held_out": {"late_and_noisy": "person:notice_delay=6,rationality=1.0", ...}}

``PopulationPolicy`` plays a population as one policy: each env draws a member at each
episode start (population play), so a learner trained beside it meets every member.
``populations/people.json`` is the shipped population of person-like leaders.
"""

from __future__ import annotations

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.card import Part, PolicyCard

PARTS = ("training", "held_out")


def load_population(spec: str) -> dict[str, str]:
    """``FILE[#PART]`` -> ``{member name: policy spec}``: one part, or both in file order.

    ``FILE`` is a path or the name of a shipped population (``people`` is ``populations/people.json``).
    """
    from colorgrid.files import JSONFileError, read_json_object
    from colorgrid.resources import find_shipped

    file, _, part = spec.partition("#")
    path = find_shipped(file, "populations", ".json")
    try:
        data = read_json_object(path, "a population: {\"training\": {name: spec}, \"held_out\": {name: spec}}")
    except JSONFileError as err:
        raise ValueError(f"population {err}") from None
    for name in PARTS:
        members = data.get(name, {})
        if not isinstance(members, dict) or not all(isinstance(v, str) for v in members.values()):
            raise ValueError(f"population {path}: {name!r} must map member names to policy specs")
    if part and part not in PARTS:
        raise ValueError(f"population part {part!r} is not one of {list(PARTS)}")
    members = {k: v for p in ((part,) if part else PARTS) for k, v in data.get(p, {}).items()}
    if not members:
        raise ValueError(f"population {spec!r} has no members")
    return members


SHIPPED_CARD = PolicyCard(lead=Part("A person-like leader from a population",
                                   "each game draws one of the population's leaders, each with its own way of playing"))
"""What a shipped population (``population:NAME[#PART]``) says of itself: each is one of person-like leaders."""


class PopulationPolicy(Policy):
    """Plays several policies as one: env ``i`` is played by member ``member[i]``, drawn at each episode start."""

    name = "population"
    state_fields = ("member",)

    def __init__(self, members: dict[str, Policy], source: str):
        self.members, self.source = members, source
        self.names = list(members)

    def describe(self) -> dict:
        return {"policy": self.name, "population": self.source,
                "members": {name: p.describe() for name, p in self.members.items()}}

    def describe_row(self, row: int) -> dict:
        """The population, and under ``member`` the member drawn for row ``row``'s episode (the one that played it)."""
        return {**self.describe(), "member": self.names[int(self.member[row])]}

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        for i, policy in enumerate(self.members.values()):
            policy.reset(config, num_envs, agent_index, seed=seed * 1000 + i)
        self.rng = np.random.default_rng([seed, agent_index, 11])
        self.member = np.zeros(num_envs, dtype=np.int64)

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        rows = self._rows(rows)
        starts = np.asarray(inp.episode_start, dtype=bool)
        member = self.member[rows]
        member[starts] = self.rng.integers(0, len(self.names), int(starts.sum()))
        self.member[rows] = member
        actions = np.zeros(len(rows), dtype=np.int64)
        for m, policy in enumerate(self.members.values()):
            mine = member == m
            if mine.any():
                actions[mine] = policy.act(inp.select(mine), rows=rows[mine]).actions
        return PolicyOutput(actions)

    def state_dict(self) -> dict:
        return {**super().state_dict(), "members": {n: p.state_dict() for n, p in self.members.items()}}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        for name, policy in self.members.items():
            policy.load_state_dict(state["members"][name])
