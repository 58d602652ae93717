"""A learner's network from a checkpoint, to go on training (``AgentConfig.init``: a warm start)."""

from __future__ import annotations

import dataclasses

from colorgrid.config import EnvConfig
from train.checkpoint import build_model, find_network, load_checkpoint
from train.config import NetConfig
from train.nets import ActorCritic, with_leader_progress
from train.policy import check_compatible


def warm_start(path: str, setting: str, name: str, agents: tuple[int, ...], net: NetConfig,
               env: EnvConfig) -> ActorCritic:
    """The network ``name`` of the checkpoint ``path`` (a run's ``setting``, e.g. ``follower.init``), to go on training
    as the network ``net`` that plays ``agents`` in ``env``: its team must fit, its network must be ``net`` (or
    ``net`` without the leader-progress input, which is added with zero weight), and it must play ``agents``."""
    ckpt = load_checkpoint(path)
    trained_env = EnvConfig.from_dict(ckpt["env_config"])
    check_compatible(trained_env, env, path)
    _, entry = find_network(ckpt, trained_env, name, f"{setting}={path!r}")
    trained = build_model(entry, trained_env, path)
    if net.leader_progress and trained.net == dataclasses.replace(net, leader_progress=False):
        trained = with_leader_progress(trained)  # the new input starts with zero weight
    role = setting.split(".")[0]
    if trained.net != net:
        raise ValueError(f"{setting}={path!r} was trained with {trained.net}, but this run "
                         f"asks for {net}; set {role}.net to match the checkpoint")
    if trained.agents != agents:
        raise ValueError(f"{setting}={path!r} was trained to play agents {list(trained.agents)}, "
                         f"but this run's {name} plays {list(agents)}")
    return trained
