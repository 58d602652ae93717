"""EnvConfig on the command line: ``--preset NAME`` or ``--config FILE.json`` plus ``--set key=value``."""

from __future__ import annotations

import argparse
from pathlib import Path

from colorgrid.config import EnvConfig
from colorgrid.configkit import apply_overrides
from colorgrid.files import JSONFileError, read_json_object
from colorgrid.presets import PRESETS, env_config

def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("environment")
    group.add_argument("--preset", default="default", choices=sorted(PRESETS), help="named setting (default: %(default)s)")
    group.add_argument("--config", type=Path, help="JSON file of EnvConfig fields")
    group.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       help="override one EnvConfig field, e.g. --set goal_reward=4 (repeatable)")


def parse_overrides(items: list[str]) -> dict:
    """``["a=1", "b=true"]`` -> ``{"a": 1, "b": True}``: EnvConfig fields, values parsed as JSON when they can be
    (the same parser as the trainer's ``--set``; ``distance_penalty_agents=leader,follower`` gives a tuple)."""
    return apply_overrides({}, items, EnvConfig, example="goal_reward=4")


def config_from_args(args: argparse.Namespace) -> EnvConfig:
    changes = {}
    if args.config is not None:
        try:
            changes.update(read_json_object(args.config, "a JSON object of EnvConfig fields"))
        except JSONFileError as err:
            raise ValueError(f"--config {err}") from None
    changes.update(parse_overrides(args.set))
    return env_config(args.preset, **changes)
