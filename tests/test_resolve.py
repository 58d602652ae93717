"""One way to resolve a configuration: ``configkit.resolve`` (a preset, then a file, then ``KEY=VALUE`` overrides),
used by ``colorgrid train``, the sweep file and the study file alike."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from colorgrid import configkit
from colorgrid.configkit import ConfigError, check_int, resolve, resolve_data

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Inner:
    size: int = 1

    def __post_init__(self):
        check_int(self, "size", 1)


@dataclass(frozen=True)
class Outer:
    NOTES = ("description",)

    name: str = "a"
    inner: Inner = field(default_factory=Inner)
    items: tuple[Inner, ...] = ()


def test_layers_apply_in_order_then_the_overrides():
    preset, file = {"name": "preset", "inner": {"size": 2}, "description": "for people"}, {"name": "file"}
    config = resolve(Outer, preset, file, overrides=["inner.size=5"])
    assert config == Outer(name="file", inner=Inner(size=5))
    assert resolve_data(preset, file, overrides=["name=set"], cls=Outer)["name"] == "set"


def test_errors_name_the_field_from_the_root_and_the_override_s_place():
    with pytest.raises(ConfigError, match=r"^inner\.size=0 is invalid: an integer >= 1"):
        resolve(Outer, {}, overrides=["inner.size=0"])
    with pytest.raises(ConfigError, match=r"^items\[1\]\.size=0 is invalid"):
        resolve(Outer, {"items": [{"size": 3}, {"size": 0}]})
    with pytest.raises(ConfigError, match=r"^set\[1\]: unknown Outer field 'colour'"):
        resolve(Outer, {}, overrides=["name=b", "colour=red"], where="set")


def test_the_train_command_the_sweep_file_and_the_study_file_resolve_through_it(monkeypatch, tmp_path):
    from server.study.config import Study, load_study
    from train.cli import resolve_config
    from train.config import TrainConfig
    from train.sweep.spec import load_sweep

    resolved = []
    original = configkit.resolve

    def spy(cls, *layers, **kwargs):
        resolved.append(cls)
        return original(cls, *layers, **kwargs)

    monkeypatch.setattr(configkit, "resolve", spy)
    file = tmp_path / "settings.json"
    file.write_text(json.dumps({"seed": 7}))
    args = argparse.Namespace(preset="default", config=str(file), set=["total_steps=4096"])
    config = resolve_config(args)
    assert (config.seed, config.total_steps) == (7, 4096) and resolved == [TrainConfig]
    load_sweep("paper_table1_small")
    assert set(resolved) == {TrainConfig} and len(resolved) > 2  # the base, then each trial's config
    load_study(ROOT / "studies" / "belief_display.toml")
    assert resolved[-1] is Study


def test_the_env_s_presets_and_command_line_resolve_through_it(monkeypatch, tmp_path):
    """``--preset``, ``--config`` and ``--set env.KEY=VALUE`` of eval, demo and replay import: the preset's layer,
    then the file's, then the overrides, built by ``configkit.resolve`` as the training config is."""
    from colorgrid.config import EnvConfig
    from colorgrid_apps.cli_env import config_from_args

    resolved = []
    original = configkit.resolve

    def spy(cls, *layers, **kwargs):
        resolved.append((cls, layers))
        return original(cls, *layers, **kwargs)

    monkeypatch.setattr(configkit, "resolve", spy)
    file = tmp_path / "env.json"
    file.write_text(json.dumps({"horizon": 40, "goal_reward": 2.0}))
    args = argparse.Namespace(preset="sparse", config=file, set=["env.goal_reward=4", "horizon=48"])
    config = config_from_args(args)
    assert (config.block_density, config.goal_reward, config.horizon) == (0.05, 4.0, 48)
    assert resolved == [(EnvConfig, ({"block_density": 0.05}, {"horizon": 48, "goal_reward": 4}))]
    with pytest.raises(ConfigError, match=r"^unknown EnvConfig field 'env.colour' in 'env.colour=1'; allowed: \["):
        config_from_args(argparse.Namespace(preset="default", config=None, set=["env.colour=1"]))
