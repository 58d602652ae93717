"""A folder of replays and its ``index.json``: one entry per replay, for people and tools to read without
opening every file (the released set in ``replays/`` and every folder ``colorgrid replay import`` writes).

The replay browser lists the files themselves (every ``*.replay.json`` under its folders, by an id made of
the path); the index adds where each came from and a description.
"""

from __future__ import annotations

import json
from pathlib import Path

from colorgrid.files import JSONFileError, atomic_path, read_json_object
from colorgrid.replay.format import Replay

INDEX_NAME = "index.json"


def index_entry(replay: Replay, file: str, description: str, **extra) -> dict:
    """One replay's entry: its ``file`` (relative to the folder), ``extra`` fields (``setting``, where it was
    imported from), its config, agents, seed and totals, and a one-line ``description``."""
    return {"file": file, **extra, "config": replay.config.to_dict(), "agents": replay.agents, "seed": replay.seed,
            "final": replay.final(), "description": description}


def write_index(folder: Path, entries: list[dict], generated_by: str) -> Path:
    """``folder/index.json`` (written atomically): the command that made the folder and its entries."""
    path = Path(folder) / INDEX_NAME
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps({"generated_by": generated_by, "replays": entries}, indent=2) + "\n")
    return path


def read_index(folder: Path) -> list[dict]:
    """The entries of ``folder/index.json``, none when the folder has no index (a release keeps some of them)."""
    path = Path(folder) / INDEX_NAME
    if not path.exists():
        return []
    entries = read_json_object(path, "a replay index (generated_by and replays)").get("replays")
    if not isinstance(entries, list) or not all(isinstance(e, dict) and isinstance(e.get("file"), str)
                                                for e in entries):
        raise JSONFileError(path, "its replays must be a list of entries, each naming its file")
    return entries
