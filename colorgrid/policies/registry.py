"""Policies by name: the scripted ones, and whatever other packages register.

Applications add policies without the core importing them: a package declares a function
under the ``colorgrid.policies`` entry point group (see ``pyproject.toml``), and that
function calls ``register_policy`` (a name, e.g. ``ippo``) or ``register_loader`` (a file
suffix, e.g. ``.pt``). The trainer registers its shipped agents and checkpoint files this way.
"""

from __future__ import annotations

from typing import Callable

from colorgrid.policies.base import Policy

Factory = Callable[[str | None], Policy]
"""``factory(role) -> Policy``; ``role`` is ``"leader"``, ``"follower"`` or None."""
Loader = Callable[[str, str | None], Policy]
"""``loader(path, role) -> Policy`` for a file of a registered suffix."""

_NAMED: dict[str, Factory] = {}
_LOADERS: dict[str, tuple[Loader, str]] = {}
_discovered = False


def register_policy(name: str, factory: Factory) -> None:
    """Make ``name`` usable anywhere a policy name is (``colorgrid eval``, training partners, the server)."""
    _NAMED[name] = factory


def register_loader(suffix: str, loader: Loader, what: str) -> None:
    """Load files ending in ``suffix`` (e.g. ``".pt"``) as policies; ``what`` names them in errors
    (e.g. ``"a checkpoint path ending in .pt"``)."""
    _LOADERS[suffix] = (loader, what)


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
    return [what for _, what in _LOADERS.values()]


def find(name: str, role: str | None) -> Policy | None:
    """The registered policy ``name`` (or file of a registered suffix), or None."""
    discover()
    if name in _NAMED:
        return _NAMED[name](role)
    for suffix, (loader, _) in _LOADERS.items():
        if name.endswith(suffix):
            return loader(name, role)
    return None
