"""Every EnvConfig validation error, and its message."""

import dataclasses

import pytest

from colorgrid import EnvConfig


def test_defaults_match_the_rules():
    cfg = EnvConfig()
    assert (cfg.height, cfg.width, cfg.num_colors, cfg.horizon) == (32, 32, 3, 128)
    assert cfg.blocks_per_color == 34 and cfg.num_blocks == 102
    assert cfg.num_actions == 4 and cfg.num_planes == 5
    assert cfg.switch_prob == pytest.approx(2 / 3 / 32)
    assert cfg.reward_mode == "shared" and cfg.asymmetric
    assert EnvConfig(allow_stay=True).num_actions == 5


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"height": 2}, r"height must be an integer in \[4, 1024\], got 2"),
        ({"width": 3.0}, r"width must be an integer"),
        ({"height": True}, r"height must be an integer"),
        ({"num_colors": 1}, r"num_colors must be an integer in \[2, 8\]"),
        ({"num_colors": 9}, r"num_colors must be an integer in \[2, 8\]"),
        ({"block_density": 0.0}, r"block_density must be large enough for at least one block per color"),
        ({"block_density": 1.5}, r"block_density must be a number in \(0, 1\)"),
        ({"block_density": 0.9995}, r"block_density must be small enough that the grid \(1024 cells\) keeps a free cell"),
        ({"hemispheres": True, "block_density": 0.9995},
         r"block_density must be small enough that each half of the grid \(512 cells\)"),
        ({"goal_reward": -1.0}, r"goal_reward must be a finite non-negative magnitude"),
        ({"wrong_penalty": -1.0}, r"wrong_penalty must be a finite non-negative magnitude"),
        ({"penalty_coef": float("nan")}, r"penalty_coef must be a finite non-negative magnitude"),
        ({"distance_penalty": -0.5}, r"distance_penalty must be a finite non-negative magnitude"),
        ({"potential_scale": -0.2}, r"potential_scale must be a finite non-negative magnitude"),
        ({"switch_prob": 1.5}, r"switch_prob must be a number in \[0, 1\]"),
        ({"horizon": 0}, r"horizon must be an integer in \[1, 1000000\]"),
        ({"distance_threshold": -1}, r"distance_threshold must be an integer in \[0, 2048\]"),
        ({"asymmetric": 1}, r"asymmetric must be a bool"),
        ({"hemispheres": "yes"}, r"hemispheres must be a bool"),
        ({"allow_stay": None}, r"allow_stay must be a bool"),
        ({"potential_shaping": 0}, r"potential_shaping must be a bool"),
        ({"reward_mode": "team"}, r"reward_mode must be one of \['shared', 'individual'\], got 'team'"),
        ({"distance_penalty_agents": ("human",)}, r"distance_penalty_agents must be a tuple of distinct names"),
        ({"distance_penalty_agents": ("leader", "leader")}, r"distance_penalty_agents must be a tuple of distinct"),
        ({"hemispheres": True, "width": 31}, r"width must be even when hemispheres=True"),
    ],
)
def test_invalid_values_raise_clear_errors(changes, message):
    with pytest.raises(ValueError, match=message):
        EnvConfig(**changes)


def test_config_is_frozen_and_replace_validates():
    cfg = EnvConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.height = 8
    assert cfg.replace(height=16).height == 16
    with pytest.raises(ValueError, match="height must be"):
        cfg.replace(height=1)


def test_from_dict_rejects_unknown_fields_and_round_trips():
    cfg = EnvConfig(reward_mode="individual", distance_penalty_agents=("leader", "follower"))
    assert EnvConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match=r"unknown EnvConfig field\(s\) \['heigth'\]; allowed: \['height'"):
        EnvConfig.from_dict({"heigth": 3})
    with pytest.raises(ValueError, match="must be built from a dict"):
        EnvConfig.from_dict([1, 2])


HOOKS_PENDING = {"server/study/config.py": "Study"}
"""Classes that still declare configkit's hooks without deriving from ``ConfigBase``, and why: the study's config
is being reworked."""


def test_every_class_that_declares_configkit_hooks_derives_from_config_base():
    """A class naming ``ERROR_STYLE``, ``UNKNOWN_STYLE``, ``CONFIG_NAME`` or ``NOTES`` says so by deriving from
    ``ConfigBase`` (``configkit.hooks`` then reads it as declared, not by ``getattr``)."""
    import ast
    import importlib

    from colorgrid.configkit import ConfigBase
    from colorgrid.configkit.checks import HOOKS
    from tests.conftest import ROOT

    found = set()
    for package in ("colorgrid", "server", "train", "colorgrid_apps"):
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef) and any(
                        isinstance(target, ast.Name) and target.id in HOOKS
                        for statement in node.body if isinstance(statement, (ast.Assign, ast.AnnAssign))
                        for target in (statement.targets if isinstance(statement, ast.Assign) else [statement.target])):
                    found.add((path.relative_to(ROOT).as_posix(), node.name))
    assert ("colorgrid/policies/people.py", "PersonStyle") in found and ("server/settings.py", "ServerSettings") in found
    plain = []
    for file, name in sorted(found):
        module = importlib.import_module(file[:-3].replace("/", "."))
        if not issubclass(getattr(module, name), ConfigBase) and HOOKS_PENDING.get(file) != name:
            plain.append(f"{file}: {name}")
    assert not plain, plain
