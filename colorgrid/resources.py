"""The files that ship with ColorGrid: pages, trained checkpoints with their cards, populations, example studies,
sweep files and released replays.

In a source checkout they are the repository's top-level folders (``web/``, ``checkpoints/``, ...). A wheel
carries the same folders as package data under ``colorgrid/_data/`` (copied there when the wheel is built,
see ``setup.py``); ``shipped`` finds them with ``importlib.resources`` in either case, so no command depends
on the working directory.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

SHIPPED = ("web", "checkpoints", "populations", "studies", "sweeps", "replays")
"""Folders that ship, under their repository names."""


def shipped(folder: str) -> Path:
    """The shipped folder ``folder`` (one of ``SHIPPED``): the wheel's copy, or the source checkout's."""
    if folder not in SHIPPED:
        raise ValueError(f"no shipped folder {folder!r}: one of {list(SHIPPED)}")
    package = files("colorgrid")
    installed = package / "_data" / folder
    if installed.is_dir():
        return Path(str(installed))
    return Path(str(package)).parent / folder  # a source checkout (or an editable install of one)


def find_shipped(name: str | Path, folder: str, suffix: str) -> Path:
    """``name`` as given when it is an existing path, else the shipped file or folder ``folder/name[suffix]``
    (``people`` -> ``populations/people.json``); a path that is neither is returned as given, for the caller
    to report as missing."""
    path = Path(name)
    if path.exists():
        return path
    for candidate in (shipped(folder) / path, shipped(folder) / f"{name}{suffix}"):
        if candidate.exists():
            return candidate
    return path


def shipped_names(folder: str, suffix: str) -> list[str]:
    """The names of the shipped files in ``folder`` ending in ``suffix`` (without it), sorted."""
    root = shipped(folder)
    return sorted(str(p.relative_to(root))[:-len(suffix)] for p in root.rglob(f"*{suffix}"))
