"""EnvConfig on the command line: ``--preset NAME`` or ``--config FILE.json`` plus ``--set env.KEY=VALUE``."""

from __future__ import annotations

import argparse
from pathlib import Path

from colorgrid.config import EnvConfig
from colorgrid.configkit import resolve_data
from colorgrid.files import JSONFileError, read_json_object
from colorgrid.presets import PRESETS, env_config

ENV_SECTION = "env"
"""Env settings are named ``env.KEY`` on every command line: ``colorgrid train`` and sweep files hold the env
under ``env`` in the training config, and ``eval``, ``demo`` and ``replay import`` take the same keys."""


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("environment")
    group.add_argument("--preset", default="default", choices=sorted(PRESETS), help="named setting (default: %(default)s)")
    group.add_argument("--config", type=Path, help="JSON file of EnvConfig fields")
    group.add_argument("--set", action="append", default=[], metavar="env.KEY=VALUE",
                       help="override one env setting (an EnvConfig field), e.g. --set env.goal_reward=4 "
                            "(repeatable); named as colorgrid train and sweep files name it (env.KEY; a bare KEY "
                            "also works here)")


def config_changes(args: argparse.Namespace) -> dict:
    """The EnvConfig fields that ``--config`` and ``--set`` give (``--set`` last), to go on top of ``--preset``:
    the layers ``configkit.resolve_data`` stacks, as every config's. ``--set`` values are parsed as JSON when they
    can be (the trainer's parser; ``env.distance_penalty_agents=leader,follower`` gives a tuple), and a key without
    ``env.`` (``a=1``, as these commands took it before) is read as ``env.a``: only env settings are set here, so it
    names nothing else."""
    file = {}
    if args.config is not None:
        try:
            file = read_json_object(args.config, "a JSON object of EnvConfig fields")
        except JSONFileError as err:
            raise ValueError(f"--config {err}") from None
    return resolve_data(file, overrides=args.set, cls=EnvConfig, section=ENV_SECTION, example="env.goal_reward=4")


def config_from_args(args: argparse.Namespace) -> EnvConfig:
    """The ``EnvConfig`` of ``--preset``, ``--config`` and ``--set`` (``colorgrid.presets.env_config``, which resolves
    it)."""
    return env_config(args.preset, **config_changes(args))
