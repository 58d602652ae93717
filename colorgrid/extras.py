"""The package's optional parts ("extras", ``pip install 'colorgrid[train]'``) and one line for a missing one.

``pip install colorgrid`` installs the core: the environment, its PettingZoo and Gymnasium views, scripted
and Bayesian policies, replays, rendering and GIF export, and the ``colorgrid`` command. The applications need
more: ``train`` (torch, TensorBoard), ``play`` (the play server), ``study``, ``viewer``, ``sweep``, ``video``
(MP4 export: imageio-ffmpeg's bundled ffmpeg). What each extra holds is read from the installed package's
own metadata (``pyproject.toml``), so this module lists no dependency a second time.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from functools import cache
from importlib.metadata import PackageNotFoundError, distribution
from typing import Callable

from packaging.requirements import Requirement

DISTRIBUTION = "colorgrid"


class MissingExtra(ImportError):
    """A job needs an extra that is not installed; the message says which, and the command that installs it."""


@cache
def extra_requirements(extra: str) -> tuple[str, ...]:
    """The distributions that ``extra`` adds (an extra it includes, such as ``colorgrid[play]``, expanded);
    empty when the package's metadata is not installed (a bare source tree: nothing can be checked)."""
    try:
        lines = distribution(DISTRIBUTION).requires or []
    except PackageNotFoundError:
        return ()
    names = []
    for line in lines:
        requirement = Requirement(line)
        if requirement.marker is None or not requirement.marker.evaluate({"extra": extra}):
            continue
        if requirement.name == DISTRIBUTION:
            names.extend(name for included in sorted(requirement.extras) for name in extra_requirements(included))
        else:
            names.append(requirement.name)
    return tuple(dict.fromkeys(names))


def missing(extra: str, only: tuple[str, ...] | None = None) -> list[str]:
    """The distributions of ``extra`` (or of ``only``, those of them it names) that are not installed."""
    out = []
    for name in extra_requirements(extra):
        if only is not None and name not in only:
            continue
        try:
            distribution(name)
        except PackageNotFoundError:
            out.append(name)
    return out


def require(extra: str, what: str, only: tuple[str, ...] | None = None) -> None:
    """Raise ``MissingExtra`` when ``what`` (e.g. ``"colorgrid train"``) cannot run: part of ``extra`` (or of
    ``only`` within it) is not installed."""
    absent = missing(extra, only)
    if absent:
        raise MissingExtra(f"{what} needs the {extra!r} extra ({', '.join(absent)} not installed): "
                           f"pip install 'colorgrid[{extra}]'")


@dataclass(frozen=True)
class Commands:
    """What an application adds to the ``colorgrid`` command line, declared under the ``colorgrid.commands``
    entry points (``pyproject.toml``). The command line reads it without importing the application: while part
    of ``extra`` is missing, each of ``names`` is still listed and says in one line how to install the extra."""

    names: tuple[str, ...]
    """The commands it adds, e.g. ``("train", "checkpoint", "train-bc")``."""
    extra: str
    """The extra they need (``pyproject.toml``'s optional dependencies)."""
    add: str
    """``"module:function"``: the function ``add(subparsers)`` that adds them, imported only once ``extra`` is
    installed."""

    def load(self) -> Callable:
        """The ``add(subparsers)`` function (an ``ImportError`` when its module cannot be imported)."""
        module, _, name = self.add.partition(":")
        return getattr(importlib.import_module(module), name)
