"""Named environment settings from the paper's experiments, and building an ``EnvConfig`` from one."""

from __future__ import annotations

from colorgrid import configkit
from colorgrid.config import EnvConfig

PRESETS: dict[str, dict] = {
    "default": {},
    "symmetric": {"asymmetric": False},
    "stationary": {"switch_prob": 0.0},
    "reward_4_1": {"goal_reward": 4.0},
    "hemispheres": {"hemispheres": True},
    "sparse": {"block_density": 0.05},
}
"""Named settings from the paper's experiments (changes from the default EnvConfig)."""


def env_config(preset: str = "default", **changes) -> EnvConfig:
    """The preset's ``EnvConfig`` with ``changes`` on top, resolved as every config is (``configkit.resolve``: the
    preset's layer, then the changes'); a clear error for an unknown preset."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
    return configkit.resolve(EnvConfig, PRESETS[preset], changes)
