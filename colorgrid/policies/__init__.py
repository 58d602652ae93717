"""Agents behind one interface (``Policy``): scripted baselines, and policies other packages register."""

from __future__ import annotations

from colorgrid.policies import registry
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.bayes import BayesConfig, BayesFollower
from colorgrid.policies.card import Part, PolicyCard
from colorgrid.policies.names import POPULATION_PREFIX, SCRIPTED, PolicyKind, policy_names, read_name
from colorgrid.policies.people import BASES, PersonLeader, PersonStyle
from colorgrid.policies.population import SHIPPED_CARD, PopulationPolicy, load_population
from colorgrid.policies.registry import scripted
from colorgrid.policies.scripted import AStarLeader, CopyFollower, IdleFollower, OracleFollower, RandomPolicy
from colorgrid.policies.shielded import ShieldedFollower, ShieldParams
from colorgrid.policies.styled import StyledLeader


def make_policy(name: str, role: str | None = None) -> Policy:
    """A policy by name: scripted (``SCRIPTED``, with parameters as ``name:key=value,...``), a population
    (``FILE.json[#PART]`` or ``population:NAME[#PART]``), or registered by an installed application (the
    trainer's shipped agents ``ippo``, ``ippo-cautious``, ... and checkpoint files ``*.pt``, which take their
    acting settings the same way: ``ippo-cautious:temperature=1``, ``x.pt:min_belief=0.5``).

    For a checkpoint holding both agents, ``role`` (``"leader"``/``"follower"``) says which to load. A person
    leader with another base than A* (``person:base=ippo-leader,slip=0.1``) is a ``StyledLeader`` (``make_styled``).
    """
    spec = read_name(name)  # what the name means: colorgrid.policies.names
    if spec is None:
        files = "".join(f" or {what}" for what in registry.registered_files())
        raise ValueError(f"unknown policy {name!r}; choose one of {policy_names()}{files}")
    if spec.kind is PolicyKind.POPULATION:
        return make_population(spec.target, role)
    if spec.kind is PolicyKind.SCRIPTED:
        kind = SCRIPTED[spec.target]
        if spec.params is None:
            return kind()
        params = parse_params(kind, spec.params, name)
        if isinstance(params, PersonStyle) and not params.around_astar:
            return make_styled(params, role, name)
        if isinstance(params, ShieldParams):
            return make_shielded(params, role, name)
        return kind(params)
    return registry.find(spec.target, role, read_params(spec.params or "", name), spec=name)


def make_styled(style: PersonStyle, role: str | None, name: str) -> StyledLeader:
    """The person leader ``name`` around its base (``style.base``, built for ``role``, a leader when None), once the
    base is known to be a leader: a policy whose card offers it as one, or a checkpoint (whose loader finds its
    leader network). A population is no base: its members are person leaders, or may each be one."""
    base = read_name(style.base)
    card = policy_card(style.base)
    if base is None:
        why = "no policy"
    elif base.kind is PolicyKind.POPULATION:
        why = "a population; give each member its own base instead"
    elif registry.file_of(style.base) is None and (card is None or card.lead is None):
        why = "not a leader policy"
    else:
        try:
            return StyledLeader(make_policy(style.base, role or "leader"), style)
        except ValueError as err:  # a checkpoint without a leader network, a base's own parameter
            raise ValueError(f"{name!r}: base {style.base!r}: {err}") from None
    raise ValueError(f"{name!r}: PersonStyle.base must be {BASES}, got {style.base!r} ({why})")


def make_shielded(params: ShieldParams, role: str | None, name: str) -> ShieldedFollower:
    """The shielded follower ``name``: its mover and its reader built for ``role`` (a follower when None)."""
    card = policy_card(params.reader)
    if card is None or not card.belief:
        raise ValueError(f"{name!r}: reader {params.reader!r} forms no belief over the goal; a Bayesian follower "
                         f"('bayes-people', 'bayes') or a trained network does")
    parts = {}
    for part, inner in params.inner().items():
        try:
            parts[part] = make_policy(inner, role or "follower")
        except ValueError as err:
            raise ValueError(f"{name!r}: {part} {inner!r}: {err}") from None
    return ShieldedFollower(params, **parts)


def inner_policies(name: str) -> dict[str, str]:
    """The policies a composite name is built from, by their part in it: a person leader's base other than A*
    (``{"base": "ippo-leader"}`` of ``person:base=ippo-leader,slip=0.1``), a shielded follower's mover and reader;
    empty for any other name, and for parameters that cannot be read (building the policy says what is wrong).
    What such a policy plays, reads and says of itself follows from these (``policy_files``, ``policy_teams``,
    ``policy_card``, ``server.followers.is_scripted``).

    A scripted policy is composite when its ``Params`` has ``inner() -> {part: name}``; its class then says what
    it is through its parts' cards (``Policy.card_around``), and ``make_policy`` builds its parts."""
    spec = read_name(name)
    if spec is None or spec.kind is not PolicyKind.SCRIPTED or spec.params is None:
        return {}
    try:
        params = parse_params(SCRIPTED[spec.target], spec.params, name)
    except (ValueError, TypeError):
        return {}
    inner = getattr(params, "inner", None)
    return inner() if inner is not None else {}


def policy_files(name: str, _within: frozenset[str] = frozenset()) -> list[str]:
    """The files policy ``name`` reads when it is built, those it names inside it too: a checkpoint (``x.pt``), a
    person leader's base (``person:base=x.pt``), a population's file and each of its members' files. A population
    file that does not exist, cannot be read or names itself is listed without members; a name that is no policy name
    lists nothing (building it says why)."""
    from colorgrid.resources import find_shipped

    spec = read_name(name)
    if spec is None:
        return []
    if spec.kind is PolicyKind.POPULATION:
        path = find_shipped(spec.target.partition("#")[0], "populations", ".json")
        if not path.exists() or str(path.resolve()) in _within:
            return [str(path)]
        try:
            members = load_population(spec.target)
        except ValueError:
            return [str(path)]
        within = _within | {str(path.resolve())}
        return list(dict.fromkeys([str(path), *(f for m in members.values() for f in policy_files(m, within))]))
    if spec.kind is PolicyKind.SCRIPTED:
        return list(dict.fromkeys(f for inner in inner_policies(name).values() for f in policy_files(inner, _within)))
    found = registry.file_of(name)
    return [found] if found is not None else []


def read_params(text: str, name: str) -> dict:
    """``"slip=0.1,notice_delay=3"`` -> ``{"slip": 0.1, "notice_delay": 3}`` (values read as JSON, else text).

    Commas inside brackets do not split: a JSON list (``steps=[1,2]``) stays whole, and a policy name with
    parameters of its own is given whole in parentheses, which are taken off
    (``reader=(bayes:rationality=3,lapse=0.05)`` -> ``"bayes:rationality=3,lapse=0.05"``)."""
    import json

    from colorgrid.configkit.build import split_outside_brackets, unwrap

    items = split_outside_brackets(text)
    if items is None:
        raise ValueError(f"{name!r}: unbalanced brackets in {text!r}; give a policy name with parameters of its own "
                         "whole in parentheses: reader=(bayes:rationality=3,lapse=0.05)")
    values = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep:
            raise ValueError(f"{name!r}: expected NAME:KEY=VALUE,KEY=VALUE, got {item!r}")
        raw, inner = raw.strip(), unwrap(raw)
        if inner != raw:  # a policy name given whole in parentheses
            values[key.strip()] = inner
            continue
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
    ``("1:1",)``), for a person leader around one (``person:base=ippo-leader``) those its base plays, and for a
    population those every member plays. Acting settings change nothing here:
    ``x.pt:temperature=0`` plays the teams ``x.pt`` plays."""
    spec = read_name(name)
    if spec is None:
        return None
    if spec.kind is PolicyKind.SCRIPTED:  # a composite (a person around a trained leader) plays what its parts play
        return _common_teams(policy_teams(inner) for inner in inner_policies(name).values())
    if spec.kind is PolicyKind.POPULATION:
        return _common_teams(policy_teams(member) for member in load_population(spec.target).values())
    return registry.teams_of(spec.target)  # ``x.pt:temperature=0`` plays the teams ``x.pt`` plays


def _common_teams(found) -> tuple[str, ...] | None:
    """The teams every one of ``found`` plays (None in it: any team); None when each plays any."""
    teams = None
    for one in found:
        if one is not None:
            teams = one if teams is None else tuple(t for t in teams if t in one)
    return teams


def policy_card(name: str) -> PolicyCard | None:
    """What the policy ``name`` says of itself (``PolicyCard``), whatever parameters the name gives: a scripted
    policy's (``registry.scripted``), a shipped population's, or what its package registered for it (a name, or
    every file of a suffix); None for a population file or a name that is no policy."""
    spec = read_name(name)
    if spec is None:
        return None
    if spec.kind is PolicyKind.SCRIPTED:
        inner = inner_policies(name)  # a composite is described through its parts' cards
        if not inner:
            return SCRIPTED[spec.target].card
        kind = SCRIPTED[spec.target]
        return kind.card_around(parse_params(kind, spec.params, name), {k: policy_card(v) for k, v in inner.items()})
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
           "PopulationPolicy", "RandomPolicy", "ShieldedFollower", "StyledLeader", "inner_policies", "make_policy",
           "offered_followers", "policy_card", "policy_teams", "scripted"]
