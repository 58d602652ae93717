"""Agents behind one interface (``Policy``): scripted baselines, and policies other packages register."""

from __future__ import annotations

from colorgrid.policies import registry
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.bayes import BayesConfig, BayesFollower, PeopleBayesFollower
from colorgrid.policies.people import PersonLeader, PersonStyle
from colorgrid.policies.population import PopulationPolicy, load_population
from colorgrid.policies.scripted import AStarLeader, CopyFollower, IdleFollower, OracleFollower, RandomPolicy

SCRIPTED = {
    "random": RandomPolicy,
    "astar": AStarLeader,
    "idle": IdleFollower,
    "copy": CopyFollower,
    "oracle": OracleFollower,
    "bayes": BayesFollower,
    "bayes-people": PeopleBayesFollower,
    "person": PersonLeader,
}
"""Scripted policies by name. ``astar`` and ``person`` need the goal (leaders); ``idle`` never collects.
Those with parameters take them in the name: ``person:slip=0.1,notice_delay=3``, ``bayes:lapse=0.2``."""


def make_policy(name: str, role: str | None = None) -> Policy:
    """A policy by name: scripted (``SCRIPTED``, with parameters as ``name:key=value,...``), a population
    (``FILE.json[#PART]`` or ``population:NAME[#PART]``), or registered by an installed application (the
    trainer's shipped agents ``ippo``, ``ippo-cautious``, ... and checkpoint files ``*.pt``, which take their
    acting settings the same way: ``ippo-cautious:temperature=1``, ``x.pt:min_belief=0.5``).

    For a checkpoint holding both agents, ``role`` (``"leader"``/``"follower"``) says which to load.
    """
    if name in SCRIPTED:
        return SCRIPTED[name]()
    if name.startswith("population:") or name.endswith(".json") or ".json#" in name:
        return make_population(name.removeprefix("population:"), role)
    base, sep, params = name.partition(":")
    if sep and base in SCRIPTED:
        return SCRIPTED[base](parse_params(SCRIPTED[base], params, name))
    registered = registry.registered_spec(name)  # a registered name or file, with parameters: ``ippo:temperature=0``
    if registered is not None:
        target, params = registered
        return registry.find(target, role, read_params(params, name), spec=name)
    files = "".join(f" or {what}" for what in registry.registered_files())
    raise ValueError(f"unknown policy {name!r}; choose one of {sorted(SCRIPTED) + registry.registered_names()}{files}")


def read_params(text: str, name: str) -> dict:
    """``"slip=0.1,notice_delay=3"`` -> ``{"slip": 0.1, "notice_delay": 3}`` (values read as JSON, else text)."""
    import json

    values = {}
    for item in filter(None, text.split(",")):
        key, sep, raw = item.partition("=")
        if not sep:
            raise ValueError(f"{name!r}: expected NAME:KEY=VALUE,KEY=VALUE, got {item!r}")
        try:
            values[key.strip()] = json.loads(raw)
        except json.JSONDecodeError:
            values[key.strip()] = raw
    return values


def parse_params(kind, text: str, name: str):
    """``"slip=0.1,notice_delay=3"`` -> ``kind.Params(slip=0.1, notice_delay=3)``."""
    import dataclasses

    params = getattr(kind, "Params", None)
    if params is None:
        raise ValueError(f"{name!r}: policy {kind.name!r} takes no parameters")
    values = read_params(text, name)
    fields = [f.name for f in dataclasses.fields(params)]
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ValueError(f"{name!r}: unknown parameter(s) {unknown} of {kind.name!r}; allowed: {fields}")
    default = getattr(kind, "default_params", None)
    return dataclasses.replace(default, **values) if default is not None else params(**values)


def policy_teams(name: str) -> tuple[str, ...] | None:
    """The teams (``"LEADERS:FOLLOWERS"``) that the policy ``name`` plays: None for any team (the scripted
    policies play any agent of any team), those its package registered for a trained network (``ippo``:
    ``("1:1",)``), and for a population those every member plays. Acting settings change nothing here:
    ``x.pt:temperature=0`` plays the teams ``x.pt`` plays."""
    if name.startswith("population:") or name.endswith(".json") or ".json#" in name:
        teams = None
        for member in load_population(name.removeprefix("population:")).values():
            found = policy_teams(member)
            if found is not None:
                teams = found if teams is None else tuple(t for t in teams if t in found)
        return teams
    if name.partition(":")[0] in SCRIPTED:
        return None
    registered = registry.registered_spec(name)  # ``x.pt:temperature=0`` plays the teams ``x.pt`` plays
    return None if registered is None else registry.teams_of(registered[0])


_OPENING: list[str] = []  # populations being built, innermost last (one naming itself would never end)


def make_population(spec: str, role: str | None = None) -> PopulationPolicy:
    """A ``PopulationPolicy`` of ``FILE[#PART]`` (see ``colorgrid.policies.population``)."""
    file = spec.partition("#")[0]
    if file in _OPENING:
        raise ValueError(f"population {file!r} contains itself (through {' -> '.join(_OPENING)})")
    _OPENING.append(file)
    try:
        members = load_population(spec)
        return PopulationPolicy({name: make_policy(member, role) for name, member in members.items()}, spec)
    finally:
        _OPENING.pop()


__all__ = ["SCRIPTED", "AgentInput", "AStarLeader", "BayesConfig", "BayesFollower", "CopyFollower", "IdleFollower",
           "OracleFollower", "PersonLeader", "PersonStyle", "Policy", "PolicyOutput", "PopulationPolicy",
           "RandomPolicy", "make_policy", "policy_teams"]
