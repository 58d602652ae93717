"""Policy pools: one policy instance serves one agent index of every live game of the same kind, in one
batched call; and what the play page shows of each AI follower and AI leader and which teams each plays, read from
what each policy says of itself (``colorgrid.policies.PolicyCard``)."""

from __future__ import annotations

import logging
import re
import time

import numpy as np

from colorgrid.config import FOLLOWER, EnvConfig
from colorgrid.enums import SeatFit
from colorgrid.env import BatchEnv
from colorgrid.policies import SCRIPTED, IdleFollower, inner_policies, make_policy, policy_card, policy_teams
from colorgrid.policies.base import AgentInput
from colorgrid.policies.names import PolicyKind, read_name
from colorgrid.replay import describe_agent
from colorgrid.step_inputs import StepInputs
from server.inference import InferenceError, InferenceLost, InferenceWorker, RemotePolicy

log = logging.getLogger("colorgrid.server")


def is_scripted(name: str) -> bool:
    """A scripted policy: cheap to build, and it plays at any agent index of any team; not a trained network or
    checkpoint (which takes a while to load: the server keeps those warm), nor a policy built around one (a person
    leader ``person:base=ippo-leader``, a shielded follower: each builds and plays as its parts)."""
    spec = read_name(name)
    if spec is None or spec.kind is not PolicyKind.SCRIPTED:
        return False
    return all(is_scripted(inner) for inner in inner_policies(name).values())


def plays(name: str, team) -> bool:
    """Whether follower ``name`` plays in ``team`` (a ``Team``): a scripted one in any, a trained network in the
    team it was trained in (``policy_teams``)."""
    teams = policy_teams(name)
    return teams is None or team.value in teams


def leads(name: str, team) -> SeatFit | None:
    """How the AI leader ``name`` plays a leader seat of ``team`` (a ``Team``): ``SeatFit.DIRECT`` (a scripted
    policy, or a network trained in that team), ``SeatFit.PAIR_VIEW`` (a network trained in the 1:1 team, in a team
    with one follower: it sees the game as a 1:1 game of its seat and the follower, ``server.seats.pair_view``), or
    None (it does not)."""
    teams = policy_teams(name)
    if teams is None or team.value in teams:
        return SeatFit.DIRECT
    return SeatFit.PAIR_VIEW if "1:1" in teams and team.num_followers == 1 else None


def follower_label(followers: tuple[str, ...]) -> str:
    """One name for a game's AI followers: the name when they are all the same kind, else ``"a + b"``; ``"none"``
    when a person plays the only follower."""
    if not followers:
        return "none"
    return followers[0] if len(set(followers)) == 1 else " + ".join(followers)


def is_leader_kind(name: str) -> bool:
    """Whether ``name`` may be an AI leader: a scripted policy whose card says how it leads (``PolicyCard.lead``,
    with parameters: ``person:slip=0.1``), a trained leader's name, a population or a checkpoint path; not a
    scripted follower's name."""
    spec = read_name(name)  # what the name means: colorgrid.policies.names
    return spec is not None and (spec.kind is not PolicyKind.SCRIPTED or SCRIPTED[spec.target].card.lead is not None)


def leader_kinds_allowed() -> str:
    """What an AI leader's name may be, in words (``is_leader_kind``)."""
    scripted = sorted(name for name, kind in SCRIPTED.items() if kind.card.lead is not None)
    return (f"a scripted leader ({', '.join(scripted)}), a trained leader's name, a population or a checkpoint path "
            "ending in .pt (not a follower)")


def follower_info(name: str) -> dict:
    """``{value, label, description, has_belief}`` for a follower name (``policy_info``)."""
    return policy_info(name, "follower")


def leader_info(name: str, pair_view: bool = False) -> dict:
    """``{value, label, description, has_belief}`` for an AI leader's name (``policy_info``); ``pair_view``: it
    leads through ``SeatFit.PAIR_VIEW``, which its description says."""
    info = policy_info(name, "leader")
    if pair_view:
        info["description"] += ("; trained beside one follower (1:1), it sees the game as 1:1: itself and the "
                                "follower (you are not in its view)")
    return info


def policy_info(name: str, role: str) -> dict:
    """``{value, label, description, has_belief}`` for a policy name of ``role``, from what the policy says of
    itself (``colorgrid.policies.policy_card``: its ``Part`` in that role, its belief). Parameters
    (``bayes:lapse=0.2``) are added to the label; a name whose card gives no part in the role (a checkpoint path)
    is labelled by its file name and what its model card's title says of it (``paper_follower.pt (imported from
    the paper's code)``); a name that says nothing of itself is taken to hold a belief."""
    card = policy_card(name)
    part = card.part(role) if card is not None else None
    has_belief = card.belief if card is not None else True
    if part is None:
        label, description = name.rsplit("/", 1)[-1], f"the {role} {name}"
        if name.endswith(".pt"):
            origin = card_origin(name)
            label += f" ({origin})" if origin else ""
            description = (f"a trained {role}{f', {origin}' if origin else ''}: loaded from {name}"
                           + (f" (its model card: {name[:-3]}.md)" if origin is not None else ""))
    else:
        params = name.partition(":")[2]
        label, description = part.label + (f" ({params})" if params else ""), part.description
    return {"value": name, "label": label, "description": description, "has_belief": has_belief}


def card_origin(checkpoint: str) -> str | None:
    """What the model card beside ``checkpoint`` (``X.md`` for ``X.pt``) says of its origin after the role in its
    title (``# Model card: `x.pt` (the follower, imported from the paper's code)`` -> ``imported from the paper's
    code``): ``""`` when it says nothing more, None without a readable card."""
    try:
        with open(checkpoint[:-3] + ".md", encoding="utf-8") as card:
            title = card.readline()
    except (OSError, UnicodeDecodeError):
        return None
    found = re.match(r"# Model card: `[^`]*` \((.*)\)\s*$", title)
    return found.group(1).partition(", ")[2] if found else None


class PolicyPool:
    """A policy playing agent ``agent_index`` (a follower, an AI leader beside a person, or the scripted leader in
    the seat of a person who left), with one row ("slot") per concurrent game of one config.

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
        self.worker = worker
        self.policy = self._new_policy()
        self.policy.reset(config, capacity, agent_index=agent_index, seed=seed)
        # whether its moves come with a belief over the goal (its card says; a checkpoint is taken to): a missed
        # deadline repeats the last belief, or before the first, the uniform one it starts from (``Game.apply``)
        self.has_belief = policy_info(name, config.roles[agent_index])["has_belief"]
        self.idle = IdleFollower()
        self.idle.reset(config, capacity, agent_index=agent_index, seed=seed + 1)
        self.capacity = capacity
        self.free = list(range(capacity - 1, -1, -1))
        self.pending = None  # the last inference call's future: the next waits until it is done (it may outlive
        # its deadline), so calls never queue up behind a slow one on old inputs
        self.last_release = time.monotonic()

    def _new_policy(self):
        role = self.config.roles[self.agent_index]
        return RemotePolicy(self.worker, self.name, role) if self.worker is not None else make_policy(self.name, role)

    def _fresh_input(self, games: int = 1) -> AgentInput:
        """The input of ``games`` games at their first step, on one fresh board."""
        env = BatchEnv(self.config, num_envs=1, seed=0)
        obs, _ = env.reset()
        one = StepInputs.begin(self.config, 1).agent_input(obs, self.agent_index, env.penalty_coef,
                                                           env.state.goal.copy())
        return AgentInput.concat([one] * games)

    def warm_up(self) -> None:
        """One call on a fresh board in a free slot, and one env step (loading the compiled kernel), so that
        the first real step is as fast as the rest."""
        slot = self.acquire()
        try:
            self.act([self._fresh_input()], [slot])
        finally:
            self.release(slot)
        env = BatchEnv(self.config, num_envs=1, seed=0)
        env.reset()
        env.step(np.zeros((1, self.config.num_agents), dtype=np.int64))

    def call_ms(self, games: int) -> float:
        """How long one call of this pool's policy takes for ``games`` games on this machine, in ms: measured on a
        policy built for it and then dropped (the pool's slots, which games may hold, are not touched)."""
        policy = self._new_policy()
        try:
            policy.reset(self.config, games, agent_index=self.agent_index)
            inputs = self._fresh_input(games)
            policy.act(inputs)  # the first call of a policy may load what it needs
            start = time.perf_counter()
            policy.act(inputs)
            return (time.perf_counter() - start) * 1000.0
        finally:
            if isinstance(policy, RemotePolicy):
                policy.close()

    def acquire(self) -> int:
        if not self.free:
            raise RuntimeError(f"policy pool {self.name!r} is full")
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

    def describe(self, slot: int | None = None) -> dict:
        """The replay's ``agents`` entry for the agent this pool plays (a checkpoint's file named); with the ``slot`` of
        a game, what that game alone had too (a population's member: ``Policy.describe_row``), asked before the slot is
        given back. Should the inference process fail to say, the entry is the policy's own."""
        description = self.policy.describe()
        if slot is not None:
            try:
                description = self.policy.describe_row(slot)
            except (InferenceLost, InferenceError, ValueError):
                log.exception("follower %s could not describe slot %d; the replay names the policy only", self.name,
                              slot)
        return describe_agent(description, self.name if self.name.endswith(".pt") else None)

    def fallback(self, inputs: list[AgentInput], slots: list[int]) -> np.ndarray:
        return self.idle.act(AgentInput.concat(inputs), rows=np.asarray(slots)).actions

    def close(self) -> None:
        """Free the policy (in the inference process, its memory there)."""
        if isinstance(self.policy, RemotePolicy):
            self.policy.close()

