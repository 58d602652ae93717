"""Follower pools: one policy instance serves one agent index of every live game of the same kind, in one
batched call."""

from __future__ import annotations

import time

import numpy as np

from colorgrid.config import FOLLOWER, EnvConfig
from colorgrid.policies import SCRIPTED, IdleFollower, make_policy, policy_teams
from colorgrid.policies.base import AgentInput
from colorgrid.replay import describe_agent
from colorgrid.step_inputs import StepInputs
from server.inference import InferenceWorker, RemotePolicy


def is_scripted(name: str) -> bool:
    """A scripted follower: cheap to build, and it plays at any agent index of any team; not a trained network
    or checkpoint (which takes a while to load: the server keeps those warm)."""
    return name.partition(":")[0] in SCRIPTED


def plays(name: str, team) -> bool:
    """Whether follower ``name`` plays in ``team`` (a ``Team``): a scripted one in any, a trained network in the
    team it was trained in (``policy_teams``)."""
    teams = policy_teams(name)
    return teams is None or team.value in teams


def follower_label(followers: tuple[str, ...]) -> str:
    """One name for a game's AI followers: the name when they are all the same kind, else ``"a + b"``."""
    return followers[0] if len(set(followers)) == 1 else " + ".join(followers)


FOLLOWER_INFO = {
    "ippo": ("Trained assistant (IPPO)", "learned from play beside a scripted leader; reads the goal from your moves",
             True),
    "ippo-people": ("Trained assistant for people (IPPO)",
                    "trained further beside leaders that slip, turn late and make mistakes", True),
    "ippo-cautious": ("Cautious trained assistant for people (IPPO)",
                      ("the trained assistant for people, trained further to take fewer wrong blocks and to read "
                       "where your moves lead; it leaves a block it is unsure of"), True),
    "ippo-1L2F": ("Trained assistant for two (IPPO, 1:2)",
                  "trained as one of two AI followers beside a scripted leader; plays only in the 1:2 team", True),
    "ippo-2L1F": ("Trained assistant for two leaders (IPPO, 2:1)",
                  "trained beside two scripted leaders; plays only in the 2:1 team", True),
    "ippo-leader": ("Trained leader (IPPO)", "the trained leader playing the follower's part: for researchers", True),
    "bayes": ("Bayesian assistant", "works out the goal from your moves and pickups, and collects once it is sure",
              True),
    "bayes-people": ("Bayesian assistant for people",
                     ("the Bayesian assistant, forgiving of late turns and slips, so a wrong move is not taken for "
                      "a goal switch"), True),
    "copy": ("Copycat", "collects the color of the last block you took that paid", False),
    "oracle": ("Oracle", "sees the goal: for researchers", False),
    "idle": ("Bystander", "walks about and never collects: you play alone", False),
    "random": ("Random mover", "moves at random and collects whatever it steps on", False),
}
"""How the play page names each scripted or shipped follower: label, one-line description, whether it holds a
belief over the goal (that the page may draw)."""


def follower_info(name: str) -> dict:
    """``{value, label, description, has_belief}`` for a follower name. Parameters (``bayes:lapse=0.2``) are
    added to the label; a name not in ``FOLLOWER_INFO`` (a checkpoint path) is labelled by its file name."""
    base, _, params = name.partition(":")
    known = FOLLOWER_INFO.get(base)
    if known is None:
        what = "a trained follower loaded from" if name.endswith(".pt") else "the follower"
        label, description, has_belief = name.rsplit("/", 1)[-1], f"{what} {name}", True
    else:
        label, description, has_belief = known
        label += f" ({params})" if params else ""
    return {"value": name, "label": label, "description": description, "has_belief": has_belief}


class FollowerPool:
    """A policy playing agent ``agent_index`` (a follower, or the scripted leader in the seat of a person who
    left), with one row ("slot") per concurrent game of one config.

    ``act`` runs the policy for any subset of slots in one call. With a ``worker`` the policy is
    built and run in the inference process (``server.inference``); without one, here. ``fallback``
    is the documented move used when inference misses its deadline: a step to a free
    neighbouring cell that collects nothing (the ``idle`` follower), always computed here.
    """

    def __init__(self, name: str, config: EnvConfig, capacity: int, seed: int = 0, agent_index: int = FOLLOWER,
                 worker: InferenceWorker | None = None):
        self.name = name
        self.config = config
        self.agent_index = agent_index
        role = config.roles[agent_index]
        self.policy = RemotePolicy(worker, name, role) if worker is not None else make_policy(name, role=role)
        self.policy.reset(config, capacity, agent_index=agent_index, seed=seed)
        self.idle = IdleFollower()
        self.idle.reset(config, capacity, agent_index=agent_index, seed=seed + 1)
        self.capacity = capacity
        self.free = list(range(capacity - 1, -1, -1))
        self.pending = None  # the last inference call's future: the next waits until it is done (it may outlive
        # its deadline), so calls never queue up behind a slow one on old inputs
        self.last_release = time.monotonic()

    def warm_up(self) -> None:
        """One call on a fresh board in a free slot, and one env step (loading the compiled kernel), so that
        the first real step is as fast as the rest."""
        from colorgrid.env import BatchEnv

        env = BatchEnv(self.config, num_envs=1, seed=0)
        obs, _ = env.reset()
        slot = self.acquire()
        try:
            inputs = StepInputs.begin(self.config, 1).agent_input(obs, self.agent_index, env.penalty_coef,
                                                                  env.state.goal.copy())
            self.act([inputs], [slot])
        finally:
            self.release(slot)
        env.step(np.zeros((1, self.config.num_agents), dtype=np.int64))

    def acquire(self) -> int:
        if not self.free:
            raise RuntimeError(f"follower pool {self.name!r} is full")
        return self.free.pop()

    def release(self, slot: int) -> None:
        self.free.append(slot)
        self.last_release = time.monotonic()

    def idle_for(self) -> float:
        """Seconds since the pool last served a game; 0 while any game uses it."""
        return time.monotonic() - self.last_release if len(self.free) == self.capacity else 0.0

    def act(self, inputs: list[AgentInput], slots: list[int]) -> tuple[np.ndarray, np.ndarray | None]:
        """Actions ``[n]`` and beliefs ``[n, C]`` (or None) for the games in ``slots``."""
        out = self.policy.act(AgentInput.concat(inputs), rows=np.asarray(slots))
        return out.actions, out.goal_probs

    def describe(self) -> dict:
        """The replay's ``agents`` entry for the agent this pool plays (a checkpoint's file named)."""
        return describe_agent(self.policy.describe(), self.name if self.name.endswith(".pt") else None)

    def fallback(self, inputs: list[AgentInput], slots: list[int]) -> np.ndarray:
        return self.idle.act(AgentInput.concat(inputs), rows=np.asarray(slots)).actions

    def close(self) -> None:
        """Free the policy (in the inference process, its memory there)."""
        if isinstance(self.policy, RemotePolicy):
            self.policy.close()

