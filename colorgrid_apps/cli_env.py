"""EnvConfig on the command line: ``--preset NAME`` or ``--config FILE.json`` plus ``--set key=value``."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from colorgrid.config import EnvConfig
from colorgrid.files import JSONFileError, read_json_object
from colorgrid.presets import PRESETS, env_config

def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("environment")
    group.add_argument("--preset", default="default", choices=sorted(PRESETS), help="named setting (default: %(default)s)")
    group.add_argument("--config", type=Path, help="JSON file of EnvConfig fields")
    group.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       help="override one EnvConfig field, e.g. --set goal_reward=4 (repeatable)")


def parse_overrides(items: list[str]) -> dict:
    """``["a=1", "b=true"]`` -> ``{"a": 1, "b": True}``; values are parsed as JSON when they can be."""
    fields = {f.name: f for f in dataclasses.fields(EnvConfig)}
    out = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep:
            raise ValueError(f"--set expects KEY=VALUE, got {item!r}")
        if key not in fields:
            raise ValueError(f"unknown EnvConfig field {key!r}; allowed: {sorted(fields)}")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        if fields[key].type in ("float",) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if key == "distance_penalty_agents" and isinstance(value, str):
            value = tuple(v for v in value.split(",") if v)
        out[key] = value
    return out


def config_from_args(args: argparse.Namespace) -> EnvConfig:
    changes = {}
    if args.config is not None:
        try:
            changes.update(read_json_object(args.config, "a JSON object of EnvConfig fields"))
        except JSONFileError as err:
            raise ValueError(f"--config {err}") from None
    changes.update(parse_overrides(args.set))
    return env_config(args.preset, **changes)
