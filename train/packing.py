"""Which trials may train as one pack (``train.pack``), without importing torch: the sweep's runner groups its
trials with these before any trial starts."""

from __future__ import annotations

from typing import Callable, Hashable, TypeVar

from train.config import TrainConfig

T = TypeVar("T")

PACK_SHAPED = ("num_envs", "num_steps", "num_minibatches", "update_epochs", "clip_vloss", "norm_adv")
"""The PPO settings every trial of a pack shares: they shape the rollout and the update's minibatches."""


def pack_fields(config: TrainConfig) -> dict[str, object]:
    """What trials must share to train in one pack, by setting: the env's team and board, the PPO settings that
    shape a rollout and an update (``PACK_SHAPED``), the device and thread count, and the evaluation and save
    cadence. Anything else (seed, lr, kappa, schedules, reward weights, target KL, partners, networks, total
    steps) may differ; networks of other shapes in a pack act and update on their own."""
    env = config.env
    return {**{f"env.{k}": getattr(env, k) for k in ("num_leaders", "num_followers", "height", "width", "num_colors")},
            **{f"ppo.{k}": getattr(config.ppo, k) for k in PACK_SHAPED},
            **{k: getattr(config, k) for k in ("device", "threads", "eval_every", "save_every")}}


def pack_key(config: TrainConfig) -> tuple:
    """``pack_fields`` as a key: trials with the same key may share a pack."""
    return tuple(pack_fields(config).values())


def check_packable(configs: list[TrainConfig]) -> None:
    """Raise a one-line ``ValueError`` naming the first trial and setting that differ from the first trial's."""
    first = pack_fields(configs[0])
    for k, config in enumerate(configs[1:], start=1):
        for name, value in pack_fields(config).items():
            if value != first[name]:
                raise ValueError(f"trial {k} of the pack has {name}={value!r} where trial 0 has {first[name]!r}: a "
                                 f"pack's trials share the env's team and board, ppo.{{{', '.join(PACK_SHAPED)}}}, "
                                 f"device, threads, eval_every and save_every")


def packs(items: list[T], key: Callable[[T], Hashable], size: int) -> list[list[T]]:
    """``items`` in packs of at most ``size``, each of items with one ``key``, as even as they can be (nine of one
    key at size 8: five and four), each pack's items in the order they come."""
    groups: dict[Hashable, list[T]] = {}
    for item in items:
        groups.setdefault(key(item), []).append(item)
    out = []
    for group in groups.values():
        count = -(-len(group) // size)
        bounds = [round(i * len(group) / count) for i in range(count + 1)]
        out.extend(group[a:b] for a, b in zip(bounds, bounds[1:]))
    return out
