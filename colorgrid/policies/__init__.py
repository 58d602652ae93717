"""Agents behind one interface (``Policy``): scripted baselines, and policies other packages register."""

from __future__ import annotations

from colorgrid.policies import registry
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.bayes import BayesConfig, BayesFollower
from colorgrid.policies.card import Part, PolicyCard
from colorgrid.policies.names import POPULATION_PREFIX, SCRIPTED, PolicyKind, policy_names, read_name
from colorgrid.policies.people import PersonLeader, PersonStyle
from colorgrid.policies.population import SHIPPED_CARD, PopulationPolicy, load_population
from colorgrid.policies.registry import scripted
from colorgrid.policies.scripted import AStarLeader, CopyFollower, IdleFollower, OracleFollower, RandomPolicy


def make_policy(name: str, role: str | None = None) -> Policy:
    """A policy by name: scripted (``SCRIPTED``, with parameters as ``name:key=value,...``), a population
    (``FILE.json[#PART]`` or ``population:NAME[#PART]``), or registered by an installed application (the
    trainer's shipped agents ``ippo``, ``ippo-cautious``, ... and checkpoint files ``*.pt``, which take their
    acting settings the same way: ``ippo-cautious:temperature=1``, ``x.pt:min_belief=0.5``).

    For a checkpoint holding both agents, ``role`` (``"leader"``/``"follower"``) says which to load.
    """
    spec = read_name(name)  # what the name means: colorgrid.policies.names
    if spec is None:
        files = "".join(f" or {what}" for what in registry.registered_files())
        raise ValueError(f"unknown policy {name!r}; choose one of {policy_names()}{files}")
    if spec.kind is PolicyKind.POPULATION:
        return make_population(spec.target, role)
    if spec.kind is PolicyKind.SCRIPTED:
        kind = SCRIPTED[spec.target]
        return kind() if spec.params is None else kind(parse_params(kind, spec.params, name))
    return registry.find(spec.target, role, read_params(spec.params or "", name), spec=name)


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
    spec = read_name(name)
    if spec is None or spec.kind is PolicyKind.SCRIPTED:
        return None
    if spec.kind is PolicyKind.POPULATION:
        teams = None
        for member in load_population(spec.target).values():
            found = policy_teams(member)
            if found is not None:
                teams = found if teams is None else tuple(t for t in teams if t in found)
        return teams
    return registry.teams_of(spec.target)  # ``x.pt:temperature=0`` plays the teams ``x.pt`` plays


def policy_card(name: str) -> PolicyCard | None:
    """What the policy ``name`` says of itself (``PolicyCard``), whatever parameters the name gives: a scripted
    policy's (``registry.scripted``), a shipped population's, or what its package registered for it (a name, or
    every file of a suffix); None for a population file or a name that is no policy."""
    spec = read_name(name)
    if spec is None:
        return None
    if spec.kind is PolicyKind.SCRIPTED:
        return SCRIPTED[spec.target].card
    if spec.kind is PolicyKind.POPULATION:
        return SHIPPED_CARD if name.startswith(POPULATION_PREFIX) else None
    return registry.card_of(spec.target)


def offered_followers() -> tuple[str, ...]:
    """The followers the play server offers when not told which: every policy whose card gives it a place in the
    menu (``PolicyCard.menu``), in that order."""
    cards = {name: policy_card(name) for name in policy_names()}
    return tuple(sorted((name for name, card in cards.items() if card is not None and card.menu is not None),
                        key=lambda name: cards[name].menu))


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
           "OracleFollower", "Part", "PersonLeader", "PersonStyle", "Policy", "PolicyCard", "PolicyOutput",
           "PopulationPolicy", "RandomPolicy", "make_policy", "offered_followers", "policy_card", "policy_teams",
           "scripted"]
