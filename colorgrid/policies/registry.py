"""Policies by name, each with its card (``colorgrid.policies.card``): the scripted ones, and whatever other
packages register.

A scripted policy registers itself where it is written: ``@scripted(PolicyCard(...))`` on its class puts it in
``SCRIPTED`` under its ``name``. Applications add policies without the core importing them: a package declares
a function under the ``colorgrid.policies`` entry point group (see ``pyproject.toml``), and that function calls
``register_policy`` (a name, e.g. ``ippo``) or ``register_loader`` (a file suffix, e.g. ``.pt``). The trainer
registers its shipped agents and checkpoint files this way.
"""

from __future__ import annotations

from typing import Callable

from colorgrid.policies.base import Policy
from colorgrid.policies.card import PolicyCard

Factory = Callable[..., Policy]
"""``factory(role, **params) -> Policy``; ``role`` is ``"leader"``, ``"follower"`` or None, ``params`` those
the name gave (``NAME:key=value,...``), each one the factory declared."""
Loader = Callable[..., Policy]
"""``loader(path, role, **params) -> Policy`` for a file of a registered suffix."""
Teams = Callable[[str], "tuple[str, ...] | None"]
"""``teams(path) -> ("1:1",)``: the teams (``"LEADERS:FOLLOWERS"``) a file's policy plays, None for any."""

SCRIPTED: dict[str, type[Policy]] = {}
"""Scripted policies by name, each registered by ``scripted`` where it is written (``colorgrid.policies.names``
imports their modules). Those with parameters take them in the name: ``person:slip=0.1,notice_delay=3``."""

_NAMED: dict[str, tuple[Factory, tuple[str, ...]]] = {}
_LOADERS: dict[str, tuple[Loader, str, tuple[str, ...]]] = {}
_CARDS: dict[str, PolicyCard] = {}  # by registered name; absent: the policy says nothing of itself
_FILE_CARDS: dict[str, PolicyCard] = {}  # by suffix
_TEAMS: dict[str, Teams] = {}  # by suffix: the teams a file's policy plays
_discovered = False


def scripted(card: PolicyCard):
    """Class decorator: register a scripted policy (a ``Policy`` subclass that sets its own ``name``) in
    ``SCRIPTED`` with its ``card`` (``kind.card``), so that its name works in ``colorgrid eval``, as a training
    partner and in the play server's menus."""

    def register(kind: type[Policy]) -> type[Policy]:
        if "name" not in vars(kind):
            raise TypeError(f"{kind.__name__} must set its own name (a class attribute) to be registered")
        kind.card = card
        SCRIPTED[kind.name] = kind
        return kind

    return register


def register_policy(name: str, factory: Factory, params: tuple[str, ...] = (), card: PolicyCard | None = None) -> None:
    """Make ``name`` usable anywhere a policy name is (``colorgrid eval``, training partners, the server);
    ``params`` are the keyword parameters it takes in the name (``NAME:key=value``); ``card`` what it says of
    itself (its labels, belief, and the teams it plays: ``("1:2",)`` for a network trained in that team)."""
    _NAMED[name] = (factory, tuple(params))
    if card is not None:
        _CARDS[name] = card


def register_loader(suffix: str, loader: Loader, what: str, params: tuple[str, ...] = (),
                    teams: Teams | None = None, card: PolicyCard | None = None) -> None:
    """Load files ending in ``suffix`` (e.g. ``".pt"``) as policies; ``what`` names them in errors
    (e.g. ``"a checkpoint path ending in .pt"``); ``params`` as for ``register_policy``; ``teams(path)`` says
    which teams a file's policy plays; ``card`` what every such file's policy says of itself (its belief)."""
    _LOADERS[suffix] = (loader, what, tuple(params))
    if teams is not None:
        _TEAMS[suffix] = teams
    if card is not None:
        _FILE_CARDS[suffix] = card


def registered_spec(spec: str) -> tuple[str, str] | None:
    """The registered policy or file that ``spec`` names, and the text of the parameters it gives: ``("x.pt",
    "temperature=0")`` for ``x.pt:temperature=0``, ``("ippo", "")`` for ``ippo``. The whole spec is tried first
    (a file's path may hold a ``:``), then the part before its first ``:``; None when neither is registered."""
    discover()

    def registered(name: str) -> bool:
        return name in _NAMED or any(name.endswith(suffix) for suffix in _LOADERS)

    if registered(spec):
        return spec, ""
    base, sep, params = spec.partition(":")
    return (base, params) if sep and registered(base) else None


def file_of(spec: str) -> str | None:
    """The file a policy ``spec`` names (one that a loader reads: ``x.pt`` of ``x.pt:temperature=0``), None for a
    registered name or a spec that is neither."""
    found = registered_spec(spec)
    return found[0] if found is not None and found[0] not in _NAMED else None


def teams_of(name: str) -> tuple[str, ...] | None:
    """The teams the registered policy ``name`` (or file) plays, None for any team or an unregistered name."""
    discover()
    if name in _NAMED:
        card = _CARDS.get(name)
        return card.teams if card is not None else None
    for suffix, found in _TEAMS.items():
        if name.endswith(suffix):
            return found(name)
    return None


def card_of(name: str) -> PolicyCard | None:
    """What the registered policy ``name`` (or a file of a registered suffix) says of itself, None if nothing."""
    discover()
    if name in _NAMED:
        return _CARDS.get(name)
    return next((card for suffix, card in _FILE_CARDS.items() if name.endswith(suffix)), None)


def discover() -> None:
    """Run every ``colorgrid.policies`` entry point once; one that cannot be imported is left out."""
    global _discovered
    if _discovered:
        return
    _discovered = True
    from importlib.metadata import entry_points

    for point in entry_points(group="colorgrid.policies"):
        try:
            register = point.load()
        except ImportError:  # that application is not installed here
            continue
        register()


def registered_names() -> list[str]:
    discover()
    return sorted(_NAMED)


def registered_files() -> list[str]:
    """What each registered file loader accepts, in words."""
    discover()
    return [what for _, what, _ in _LOADERS.values()]


def find(name: str, role: str | None, params: dict | None = None, spec: str | None = None) -> Policy | None:
    """The registered policy ``name`` (or file of a registered suffix) with ``params``, or None.

    A parameter the policy does not declare is refused with the ones it takes (``spec``, the whole name
    as given, names it in the message)."""
    discover()
    params = params or {}
    if name in _NAMED:
        factory, allowed = _NAMED[name]
        return factory(role, **_checked(params, allowed, spec or name, repr(name)))
    for suffix, (loader, what, allowed) in _LOADERS.items():
        if name.endswith(suffix):
            return loader(name, role, **_checked(params, allowed, spec or name, what))
    return None


def _checked(params: dict, allowed: tuple[str, ...], spec: str, what: str) -> dict:
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        takes = f"allowed: {list(allowed)}" if allowed else "it takes none"
        raise ValueError(f"{spec!r}: unknown parameter(s) {unknown} of {what}; {takes}")
    return params
