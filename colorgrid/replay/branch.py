"""What would another assistant have done here? Branching a replay, and rescoring recorded games.

``branch`` continues a recorded episode from the exact state at step T with another follower
(or the same one with another seed). The first T steps are the parent's: the env re-simulates
them from the seed and the recorded actions, and the new follower watches them (it is fed
every input it would have seen, and its actions are ignored), so that its beliefs and memory
at step T come from the same history. From step T the follower acts; the leader replays its
recorded actions (the default) or is a policy.

``rescore`` branches every recorded game at step 0 with each follower and compares them on the
same leader moves. That is open-loop: the person did not see the new follower and did not
react to it, so it measures how a follower does beside these exact moves, not how the game
would have gone. A study's practice games and games that showed the person the goal are
rescored apart (``colorgrid.replay.apart``), never pooled with the others.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from colorgrid.config import FOLLOWER, LEADER
from colorgrid.enums import Ending
from colorgrid.env import BatchEnv
from colorgrid.policies import make_policy
from colorgrid.replay import Replay, ReplayError, describe_agent, load
from colorgrid.replay.apart import SET_APART, set_apart
from colorgrid.step_inputs import StepInputs


def branch(parent: Replay, step: int, follower: str, leader: str = "recorded", seed: int | None = None,
           parent_name: str | None = None) -> Replay:
    """The episode of ``parent`` continued from step ``step`` (0..T) with ``follower`` (and ``leader``)."""
    if parent.kind != "actions":
        raise ReplayError(parent_name, "only actions replays can be branched (a frames replay has no seed)")
    if not parent.config.one_to_one:
        raise ReplayError(parent_name, f"only 1:1 replays can be branched; this one's team is {parent.config.team}")
    T = parent.num_steps
    if not 0 <= step <= T:
        raise ValueError(f"--step must be in [0, {T}] (the parent has {T} steps), got {step}")
    cfg = parent.config
    seed = parent.seed if seed is None else seed
    follower_policy = make_policy(follower, role="follower")
    follower_policy.reset(cfg, 1, FOLLOWER, seed=seed)
    leader_policy = None
    if leader != "recorded":
        leader_policy = make_policy(leader, role="leader")
        leader_policy.reset(cfg, 1, LEADER, seed=seed)
    env = BatchEnv(cfg, num_envs=1, seed=parent.seed, autoreset=False)
    obs, _ = env.reset()
    env.penalty_coef = parent.penalty_coef
    last = StepInputs.begin(cfg, 1)
    # the leader's recorded moves set the length; a leader policy plays to the horizon
    length = T if leader_policy is None else cfg.horizon
    record: dict[str, list] = {k: [] for k in ("actions", "goal", "block_reward", "team_reward", "picked_color",
                                               "goal_switched", "beliefs")}
    hashes = [env.state.state_hash(0)]
    for t in range(length):
        goal = env.state.goal.copy()
        out = follower_policy.act(last.agent_input(obs, FOLLOWER, env.penalty_coef, goal.copy()))
        lead = leader_policy.act(last.agent_input(obs, LEADER, env.penalty_coef, goal.copy())).actions[0] \
            if leader_policy is not None else None
        if t < step:  # the parent's step: the new agents watch, the recorded actions play
            joint = list(parent.actions[t])
        else:
            joint = [int(lead) if lead is not None else parent.actions[t][LEADER], int(out.actions[0])]
        actions = np.array([joint], dtype=np.int64)
        obs, _, _, truncs, info = env.step(actions)
        last.record(actions, info)
        record["actions"].append(joint)
        record["goal"].append(int(goal[0]))
        record["block_reward"].append([float(x) for x in info["block_reward"][0]])
        record["team_reward"].append(float(info["team_reward"][0]))
        record["picked_color"].append([int(x) for x in info["picked_color"][0]])
        record["goal_switched"].append(bool(info["goal_switched"][0]))
        if out.goal_probs is not None:
            record["beliefs"].append([round(float(p), 5) for p in out.goal_probs[0]])
        hashes.append(env.state.state_hash(0))
        if truncs.all():
            break
    agents = dict(parent.agents)
    agents["follower"] = describe_agent(follower_policy.describe(), follower if follower.endswith(".pt") else None)
    if leader_policy is not None:
        agents["leader"] = describe_agent(leader_policy.describe(), leader if leader.endswith(".pt") else None)
    keys = [e for e in (parent.key_events or []) if e.get("applied_step") is None or e["applied_step"] < step] \
        if parent.key_events is not None else None
    beliefs = record.pop("beliefs")
    steps = len(record["actions"])
    return Replay(
        config=cfg, seed=parent.seed, source=parent.source, agents=agents,
        goal_probs={"follower": beliefs} if len(beliefs) == steps else {}, state_hashes=hashes,
        penalty_coef=parent.penalty_coef, ended=Ending.COMPLETE if steps == cfg.horizon else parent.ended,
        key_events=keys,
        meta={**{k: v for k, v in parent.meta.items() if k not in ("state_sent_ms", "deadline_misses")},
              "branch_of": {"file": parent_name, "created": parent.created, "step": step,
                            "parent_checksum": parent.to_document()["checksum"]},
              "branch": {"step": step, "follower": follower, "leader": leader, "follower_seed": seed}},
        **record,
    )


def watch(replay: Replay, follower: str, agent: int, seed: int | None = None) -> list[list[float]] | None:
    """The beliefs ``[T][C]`` that ``follower`` forms when it watches ``replay`` from the seat of agent ``agent`` (any
    team): the env re-simulates the recorded actions, the follower gets every input that seat had and its actions are
    ignored, so at every step its belief comes from the very history the agent saw (a person's, say). None for a
    follower that forms no belief."""
    if replay.kind != "actions":
        raise ReplayError(None, "only actions replays can be watched (a frames replay has no seed)")
    cfg = replay.config
    policy = make_policy(follower, role="follower")
    policy.reset(cfg, 1, agent, seed=replay.seed if seed is None else seed)
    env = BatchEnv(cfg, num_envs=1, seed=replay.seed, autoreset=False)
    obs, _ = env.reset()
    env.penalty_coef = replay.penalty_coef
    last = StepInputs.begin(cfg, 1)
    beliefs = []
    for t in range(replay.num_steps):
        out = policy.act(last.agent_input(obs, agent, env.penalty_coef, env.state.goal.copy()))
        if out.goal_probs is None:
            return None
        beliefs.append([round(float(p), 5) for p in out.goal_probs[0]])
        actions = np.array([replay.actions[t]], dtype=np.int64)
        obs, _, _, _, info = env.step(actions)
        last.record(actions, info)
    return beliefs


def open_loop_pickups(parent: Replay, follower: str, seed: int | None = None,
                      parent_name: str | None = None) -> tuple[int, int]:
    """The net and wrong pickups of ``follower`` playing the follower seat of the 1:1 game ``parent`` from its first
    step, beside the recorded leader's moves (``branch`` at step 0): what ``rescore`` counts for each game."""
    final = branch(parent, 0, follower, seed=seed, parent_name=parent_name).final()
    return final["follower_goal_pickups"] - final["follower_wrong_pickups"], final["follower_wrong_pickups"]


def rescore(files: list[Path], followers: list[str], seed: int | None = None) -> dict:
    """Every recorded leader's moves replayed with each follower (``branch`` at step 0): per-follower means
    and paired differences against the first follower, with 95% intervals over games. The games ``set_apart``
    names (a study's practice, the goal shown to a person) are pooled apart, each kind under ``set_apart`` in a
    report of the same fields (``games`` may then be empty)."""
    kinds: dict[str | None, list[tuple[str, Replay]]] = {None: []}
    for path in files:
        parent = load(path)
        if parent.kind != "actions" or "branch_of" in parent.meta:  # a branch's leader moves are open-loop copies
            continue
        if not parent.config.one_to_one:  # a team's followers are not replaced one at a time
            continue
        kinds.setdefault(set_apart(parent), []).append((str(path), parent))
    if not any(kinds.values()):
        raise ValueError("no actions replays to rescore")
    return {**_rescored(kinds.pop(None), followers, seed),
            "set_apart": {kind: _rescored(games, followers, seed) for kind, games in kinds.items()}}


def _rescored(games: list[tuple[str, Replay]], followers: list[str], seed: int | None) -> dict:
    """``rescore``'s figures over ``games`` (path and replay), pooled together."""
    from colorgrid.evaluate import mean_ci

    pickups = {f: [open_loop_pickups(parent, f, seed, path) for path, parent in games] for f in followers}
    nets = {f: [net for net, _ in pickups[f]] for f in followers}
    wrongs = {f: [wrong for _, wrong in pickups[f]] for f in followers}
    base = followers[0]
    out = {"games": [path for path, _ in games], "followers": followers, "baseline": base,
           "net_pickups": {}, "wrong_pickups": {}, "paired_difference": {}, "per_game": nets, "per_game_wrong": wrongs}
    if games:  # no figure over no game
        out.update(net_pickups={f: mean_ci(np.array(nets[f])) for f in followers},
                   wrong_pickups={f: mean_ci(np.array(wrongs[f])) for f in followers},
                   paired_difference={f: mean_ci(np.array(nets[f]) - np.array(nets[base])) for f in followers[1:]})
    return out


def format_rescore(report: dict) -> str:
    """``rescore``'s report as a table; an interval only where there are two games or more. Each kind of game set
    apart follows in a table of its own."""
    lines = _rescore_table(report) if report["games"] else [
        "no recorded game to pool: every game rescored is set apart below"]
    for kind, part in report.get("set_apart", {}).items():
        lines += ["", f"set apart, not pooled above: {len(part['games'])} {SET_APART[kind].games}", *_rescore_table(part)]
    return "\n".join(lines)


def _rescore_table(report: dict) -> list[str]:
    from colorgrid.evaluate import format_mean_ci

    lines = [f"{len(report['games'])} recorded games, each leader's moves replayed open-loop with each follower",
             f"{'follower':<36}{'net pickups ± 95%':>22}{'wrong pickups':>16}"]
    for f in report["followers"]:
        n, w = report["net_pickups"][f], report["wrong_pickups"][f]
        lines.append(f"{f:<36}{format_mean_ci(n):>22}{w['mean']:>16.2f}")
    for f, d in report["paired_difference"].items():
        lines.append(f"{f} - {report['baseline']}: {format_mean_ci(d)} net pickups per game (paired)")
    return lines
