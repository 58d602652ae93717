"""What the trainer adds to the core: its shipped agents by name and checkpoint files as policies, and its
commands.

Registered through the ``colorgrid.policies`` and ``colorgrid.commands`` entry points (``pyproject.toml``); torch
is imported only when one of these policies is asked for or one of the commands runs.
"""

from __future__ import annotations

from colorgrid.extras import Commands, require
from colorgrid.policies.card import Part, PolicyCard
from colorgrid.resources import shipped
from train.acting import ACTING
from train.model_cache import ModelCache

TRAIN_COMMANDS = Commands(("train", "checkpoint", "train-bc"), "train", "train.cli:add_train_commands")
"""``colorgrid train``, ``checkpoint`` and ``train-bc`` (the ``colorgrid.commands`` entry point ``train``)."""
SWEEP_COMMANDS = Commands(("sweep",), "sweep", "train.sweep.cli:add_sweep_commands")
"""``colorgrid sweep`` (the ``colorgrid.commands`` entry point ``sweep``)."""

CHECKPOINTS_DIR = shipped("checkpoints")
SHIPPED = {"ippo": "follower.pt", "ippo-people": "follower_people.pt", "ippo-cautious": "follower_cautious.pt",
           "ippo-leader": "leader.pt", "ippo-1L2F": "follower_1L2F.pt", "ippo-2L1F": "follower_2L1F.pt"}
"""Trained agents that ship in ``checkpoints/``, by name: the IPPO follower (trained beside A*), the same follower
trained further beside a population of person-like leaders, that one trained further to take fewer wrong blocks,
the IPPO leader, and the followers of the 1:2 and 2:1 teams (see their model cards)."""
LEADER_STAGES = {"0.2M": "an early stage: heads for blocks, a third of its pickups wrong",
                 "0.4M": "a novice: about one wrong block in five pickups",
                 "0.8M": "an intermediate stage: about 3 wrong blocks an episode",
                 "2.5M": "the end of its run: as good as the trained leader"}
"""Leaders saved along one training run (``checkpoints/leader_stages/``, their model cards beside them), shipped as
training partners at several skill levels: ``ippo-leader-0.2M`` and so on, by the steps each had trained."""
SHIPPED.update({f"ippo-leader-{stage}": f"leader_stages/leader_{stage}.pt" for stage in LEADER_STAGES})
SHIELDED = {"ippo-shielded": "shielded:mover=ippo-people,reader=bayes-people,min_belief=0.8"}
"""Shipped shielded followers (``colorgrid/policies/shielded.py``) by name: ``ippo-people``'s moves, kept off any block
whose color ``bayes-people``'s belief gives less than 0.8. Its model card is ``checkpoints/follower_shielded.md``; the
claims that made it the play server's default, declared before the data, are in ``docs/reproduction/shielded/``."""
SHIPPED_CARDS = {
    "ippo-shielded": PolicyCard(follow=Part("Shielded assistant for people",
                                            ("the trained assistant for people, kept off any block the Bayesian "
                                             "assistant is unsure of: it collects boldly and rarely errs")),
                                belief=True, menu=5, teams=("1:1",)),
    "ippo": PolicyCard(follow=Part("Trained assistant (IPPO)",
                                   "learned from play beside a scripted leader; reads the goal from your moves"),
                       belief=True, menu=40, teams=("1:1",)),
    "ippo-people": PolicyCard(follow=Part("Trained assistant for people (IPPO)",
                                          "trained further beside leaders that slip, turn late and make mistakes"),
                              belief=True, menu=30, teams=("1:1",)),
    "ippo-cautious": PolicyCard(follow=Part("Cautious trained assistant for people (IPPO)",
                                            ("the trained assistant for people, trained further to take fewer wrong "
                                             "blocks and to read where your moves lead; it leaves a block it is unsure "
                                             "of")),
                                belief=True, menu=20, teams=("1:1",)),
    "ippo-1L2F": PolicyCard(follow=Part("Trained assistant for two (IPPO, 1:2)",
                                        ("trained as one of two AI followers beside a scripted leader; plays only in "
                                         "the 1:2 team")),
                            belief=True, menu=50, teams=("1:2",)),
    "ippo-2L1F": PolicyCard(follow=Part("Trained assistant for two leaders (IPPO, 2:1)",
                                        "trained beside two scripted leaders; plays only in the 2:1 team"),
                            belief=True, menu=60, teams=("2:1",)),
    "ippo-leader": PolicyCard(lead=Part("Trained leader (IPPO)", "the network trained to lead beside a follower (1:1)"),
                              follow=Part("Trained leader (IPPO)",
                                          "the trained leader playing the follower's part: for researchers"),
                              belief=True, teams=("1:1",)),
    **{f"ippo-leader-{stage}": PolicyCard(lead=Part(f"Trained leader (IPPO) at {stage} steps", words),
                                          belief=True, teams=("1:1",)) for stage, words in LEADER_STAGES.items()},
}
"""What each shipped agent says of itself (``colorgrid.policies.PolicyCard``): how the play page calls it, the team
it plays, and its place in the page's follower menu (the trained leader is offered there only when named)."""
CHECKPOINT_CARD = PolicyCard(belief=True)
"""What every checkpoint file's policy says of itself: its goal head gives a belief over the goal (the page names
the file; its team is read from the file, ``checkpoint_teams``)."""


def shipped_policy(name: str, role: str | None, cache: ModelCache | None = None, **acting):
    require("train", f"the trained policy {name!r}", only=("torch",))
    path = CHECKPOINTS_DIR / SHIPPED[name]
    if not path.is_file():
        raise ValueError(f"the shipped checkpoint for {name!r} is missing: {path} (it ships with colorgrid: reinstall it)")
    policy = checkpoint_policy(str(path), role, cache, **acting)
    policy.name = name
    return policy


def shielded_policy(name: str, role: str | None):
    """The shipped shielded follower ``name`` (``SHIELDED``), named by that name in replays and reports."""
    from colorgrid.policies import make_policy

    policy = make_policy(SHIELDED[name], role)
    policy.name = name
    return policy


def checkpoint_policy(path: str, role: str | None, cache: ModelCache | None = None, **acting):
    """``acting``: settings from the name (``x.pt:min_belief=0.7``), see ``train.policy.NetPolicy``."""
    require("train", f"the checkpoint policy {path!r}", only=("torch",))
    from train.policy import load_policy

    return load_policy(path, role=role, cache=cache, **acting)


def checkpoint_teams(path: str) -> tuple[str, ...] | None:
    """The team a checkpoint file was trained in (``("1:2",)``), from its env config; None if it cannot be read
    (loading it will say why)."""
    try:
        from train.checkpoint import load_checkpoint

        env = load_checkpoint(path)["env_config"]
    except (ImportError, OSError, ValueError, KeyError):  # no torch, or not a checkpoint: make_policy reports it
        return None
    return (f"{env.get('num_leaders', 1)}:{env.get('num_followers', 1)}",)


def register_policies() -> None:
    """The ``colorgrid.policies`` entry point: the loaders it registers share one ``ModelCache``. Shipped agents
    whose file is missing (a team follower not yet trained) are not offered."""
    from colorgrid.policies.registry import register_loader, register_policy

    cache = ModelCache()
    for name, file in SHIPPED.items():
        if not (CHECKPOINTS_DIR / file).is_file():
            continue
        register_policy(name, lambda role, name=name, **params: shipped_policy(name, role, cache, **params),
                        params=tuple(ACTING), card=SHIPPED_CARDS[name])
    for name in SHIELDED if (CHECKPOINTS_DIR / SHIPPED["ippo-people"]).is_file() else ():  # its mover's weights
        register_policy(name, lambda role, name=name: shielded_policy(name, role), card=SHIPPED_CARDS[name])
    register_loader(".pt", lambda path, role, **params: checkpoint_policy(path, role, cache, **params),
                    "a checkpoint path ending in .pt", params=tuple(ACTING), teams=checkpoint_teams,
                    card=CHECKPOINT_CARD)
