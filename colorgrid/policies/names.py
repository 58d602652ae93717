"""What a policy name means, read from its form alone: the one statement of the rules that ``make_policy``, the
trainer's config and the play server's settings all follow.

A policy name is one of (nothing is built or loaded to tell which):

- a scripted policy (``SCRIPTED``), with parameters as ``name:key=value,...`` (``person:slip=0.1``);
- a population of policies: ``population:NAME[#PART]`` (a shipped one, ``population:people#held_out``) or
  ``FILE.json[#PART]``;
- a name or file an installed application registered (``colorgrid.policies.registry``): the trainer's shipped
  agents (``ippo``) and its checkpoint files (``x.pt``), with parameters the same way (``x.pt:temperature=0``).

The rules are tried in that order, a scripted name written whole first.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from colorgrid.policies import bayes, limit, people, registry, scripted, shielded  # noqa: F401 (each registers its policies)
from colorgrid.policies.registry import SCRIPTED

POPULATION_PREFIX = "population:"
"""The prefix of a shipped population's name (``population:people#held_out``); a population file needs none."""


class PolicyKind(enum.Enum):
    """What kind of policy a name names."""

    SCRIPTED = "scripted"
    POPULATION = "population"
    REGISTERED = "registered"


@dataclass(frozen=True)
class PolicyName:
    """A policy name as read by ``read_name``: its kind, what it names, and the parameters it gives."""

    kind: PolicyKind
    target: str
    """The scripted policy's name; the population (``NAME[#PART]`` or ``FILE.json[#PART]``, without
    ``population:``); or the registered name or file (``ippo``, ``x.pt``)."""
    params: str | None = None
    """The parameters' text after the first ``:`` (``"slip=0.1,notice_delay=3"``); None when the name gives none."""


def is_population(name: str) -> bool:
    """Whether ``name`` names a population: ``population:NAME[#PART]`` or ``FILE.json[#PART]`` (not a scripted
    policy whose parameters name one: ``person:base=(p.json#a),slip=0.1``)."""
    if name.partition(":")[0] in SCRIPTED:
        return False
    return name.startswith(POPULATION_PREFIX) or name.endswith(".json") or ".json#" in name


def read_name(name: str) -> PolicyName | None:
    """What the policy name ``name`` means (module docstring), None when it is no policy name. Only the form is
    read: a parameter's name or value, a population's file and a checkpoint's contents are checked when the
    policy is built (``make_policy``)."""
    if name in SCRIPTED:
        return PolicyName(PolicyKind.SCRIPTED, name)
    if is_population(name):
        return PolicyName(PolicyKind.POPULATION, name.removeprefix(POPULATION_PREFIX))
    base, sep, params = name.partition(":")
    if sep and base in SCRIPTED:
        return PolicyName(PolicyKind.SCRIPTED, base, params)
    registered = registry.registered_spec(name)  # a registered name or file, with parameters: ``ippo:temperature=0``
    if registered is not None:
        target, params = registered
        return PolicyName(PolicyKind.REGISTERED, target, params or None)
    return None


def policy_names() -> list[str]:
    """Every policy known by name: the scripted ones, then those installed applications registered."""
    return sorted(SCRIPTED) + registry.registered_names()
