"""Which trials may train as one pack (``train.pack``), without importing torch: the sweep's runner groups its
trials with these before any trial starts."""

from __future__ import annotations

from typing import Callable, Hashable, TypeVar

from train.config import TrainConfig

T = TypeVar("T")

PACK_SHAPED = ("num_envs", "num_steps", "num_minibatches", "update_epochs", "clip_vloss", "norm_adv")
"""The PPO settings every trial of a pack shares: they shape the rollout and the update's minibatches."""


def pack_key(config: TrainConfig) -> tuple:
    """What trials must share to train in one pack: the env's team and board, the PPO settings that shape a
    rollout and an update (``PACK_SHAPED``), the device and thread count, and the evaluation and save cadence.
    Anything else (seed, lr, kappa, schedules, reward weights, target KL, partners, networks, total steps) may
    differ; networks of other shapes in a pack act and update on their own."""
    env = config.env
    return (env.num_leaders, env.num_followers, env.height, env.width, env.num_colors,
            tuple(getattr(config.ppo, name) for name in PACK_SHAPED), config.device, config.threads,
            config.eval_every, config.save_every)


def check_packable(configs: list[TrainConfig]) -> None:
    """Raise a one-line ``ValueError`` naming the first trial whose shape differs from the first's."""
    first = pack_key(configs[0])
    for k, config in enumerate(configs[1:], start=1):
        if pack_key(config) != first:
            raise ValueError(f"trial {k} (seed {config.seed}) cannot share a pack with trial 0 (seed "
                             f"{configs[0].seed}): a pack's trials share the env's team and board, ppo."
                             f"{{{', '.join(PACK_SHAPED)}}}, device, threads, eval_every and save_every")


def packs(items: list[T], key: Callable[[T], Hashable], size: int) -> list[list[T]]:
    """``items`` in packs of at most ``size``, each of items with one ``key`` (in the order the items come: the
    first pack holds the first item)."""
    groups: dict[Hashable, list[T]] = {}
    for item in items:
        groups.setdefault(key(item), []).append(item)
    return [group[i:i + size] for group in groups.values() for i in range(0, len(group), size)]
