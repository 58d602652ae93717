"""The evaluation harness: metrics over a batch of episodes, as a table and as JSON.

Any team shape: one policy per agent (``leader`` for every leader, ``follower`` for every follower, ``agents``
for one agent by name: ``colorgrid eval --leader``, ``--follower``, ``--agent NAME=POLICY``), metrics per agent
and, beyond the 1:1 team, per role.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from colorgrid.config import ROLES, EnvConfig
from colorgrid.enums import Role
from colorgrid.policies import Policy, make_policy
from colorgrid.policies.names import read_name
from colorgrid.rollout import EpisodeBatch, run_team


def mean_ci(values: np.ndarray) -> dict:
    """Mean and the half-width of its 95% normal confidence interval."""
    values = np.asarray(values, dtype=np.float64)
    n = values.size
    half = 1.96 * values.std(ddof=1) / np.sqrt(n) if n > 1 else float("nan")
    return {"mean": float(values.mean()), "ci95": float(half)}


def format_mean_ci(m: dict, form: str = "{:+.2f}") -> str:
    """``mean_ci``'s figure as text, ``+1.25 ± 0.40``; the mean alone where there is no interval (one value: its
    ``ci95`` is NaN), never ``± nan``."""
    mean = form.format(m["mean"])
    return mean if not np.isfinite(m["ci95"]) else f"{mean} ± {form.format(m['ci95']).lstrip('+')}"


def summarize(batch: EpisodeBatch) -> dict:
    """Per-agent and team metrics of a batch of episodes, and per-role ones beyond the 1:1 team (see
    docs/EVALUATION.md)."""
    config = batch.config
    agents = {name: _agent_metrics(batch, i) for i, name in enumerate(config.agent_names)}
    report = {"agents": agents}
    if not config.one_to_one:
        report["roles"] = {role: _role_metrics(batch, agents, role) for role in ROLES}
    report.update({
        "team_reward": mean_ci(batch.team_reward.sum(axis=0)),
        "goal_switches_per_episode": float(batch.goal_switched.sum(axis=0).mean()),
    })
    return report


def _pickups(batch: EpisodeBatch, agents: list[int]) -> tuple[dict, np.ndarray]:
    """Per-episode totals of ``agents`` together: their rewards and pickups, and their net pickups ``[B]``."""
    goal = batch.goal_pickup[:, :, agents].sum(axis=(0, 2))
    wrong = batch.wrong_pickup[:, :, agents].sum(axis=(0, 2))
    return {"block_reward": mean_ci(batch.block_reward[:, :, agents].sum(axis=(0, 2))), "goal_pickups": mean_ci(goal),
            "wrong_pickups": mean_ci(wrong), "net_pickups": mean_ci(goal - wrong)}, goal - wrong


def _agent_metrics(batch: EpisodeBatch, i: int) -> dict:
    entry, _ = _pickups(batch, [i])
    probs = batch.goal_probs[i]
    if probs is not None:
        truth = np.take_along_axis(probs, batch.goal[:, :, None], axis=2)[..., 0]  # [T, B]
        entry["belief"] = {
            "accuracy": float((probs.argmax(axis=2) == batch.goal).mean()),
            "log_loss": float(-np.log(np.clip(truth, 1e-6, 1.0)).mean()) + 0.0,
        }
    return entry


def _role_metrics(batch: EpisodeBatch, agents: dict, role: str) -> dict:
    """A role's totals per episode (summed over its agents), its net pickups per agent, and the mean belief
    metrics of its agents that hold a belief."""
    config = batch.config
    members = [i for i, r in enumerate(config.roles) if r == role]
    totals, net = _pickups(batch, members)
    entry = {"agents": len(members), **totals, "net_pickups_per_agent": mean_ci(net / len(members))}
    beliefs = [agents[config.agent_names[i]]["belief"] for i in members if "belief" in agents[config.agent_names[i]]]
    if beliefs:
        entry["belief"] = {"agents": len(beliefs),
                           "accuracy": float(np.mean([b["accuracy"] for b in beliefs])),
                           "log_loss": float(np.mean([b["log_loss"] for b in beliefs]))}
    return entry


def switch_lags(goal_probs: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Steps from each goal switch until the belief's argmax names the new goal.

    goal_probs: [T, B, C] beliefs when acting; goal: [T, B] true goal at those steps.
    Switches followed by another switch (or the episode end) before the belief
    catches up are left out.
    """
    return catch_lags(goal_probs.argmax(axis=2) == goal, goal)


def catch_lags(right: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Steps from each goal switch until a belief is ``right`` (``[T, B]`` bool: it names the goal at step t; a
    person's stated belief, or a follower's argmax), for every switch caught before the next one or the end.

    The switch at the end of step t - 1 is caught after k steps when step t + k is the first whose belief is right."""
    T, B = goal.shape
    lags = []
    for e in range(B):
        for t in range(1, T):
            if goal[t, e] == goal[t - 1, e]:
                continue
            k = 0
            while t + k < T and goal[t + k, e] == goal[t, e] and not right[t + k, e]:
                k += 1
            if t + k < T and goal[t + k, e] == goal[t, e]:
                lags.append(k)
    return np.array(lags, dtype=np.int64)


def team_specs(config: EnvConfig, leader: str | Policy, follower: str | Policy,
               agents: Mapping[str, str | Policy] | None = None) -> list[str | Policy]:
    """One policy (a name or a ``Policy``) per agent, in index order: ``leader`` for every leader, ``follower``
    for every follower, and ``agents`` (agent name -> policy) in place of those it names."""
    agents = dict(agents or {})
    for name in agents:
        config.index(name)  # an unknown name is an error that lists the team's agents
    return [agents.get(name, leader if role == Role.LEADER else follower)
            for name, role in zip(config.agent_names, config.roles)]  # run_team refuses one object for two


def evaluate(config: EnvConfig, leader: str | Policy, follower: str | Policy, episodes: int, seed: int,
             record_dir: str | Path | None = None, agents: Mapping[str, str | Policy] | None = None) -> dict:
    """Run ``episodes`` episodes (env i seeded ``seed + i``) and summarize them.

    ``leader`` and ``follower`` are policy names (scripted or ``.pt`` checkpoints) or ``Policy`` objects,
    for every agent of the role (in a team of several, a name builds one policy per agent); ``agents``
    sets single agents' policies by name (``{"leader_1": "person:slip=0.1"}``). With ``record_dir``,
    every episode is also saved there as a replay.
    """
    start, cpu = time.perf_counter(), time.process_time()
    specs = team_specs(config, leader, follower, agents)
    policies = [_policy(spec, role) for spec, role in zip(specs, config.roles)]
    names = [_name(spec) for spec in specs]
    batch = run_team(config, policies, episodes, seed, record_hashes=record_dir is not None)
    report = summarize(batch)
    if record_dir is not None:
        report["replays"] = [str(p) for p in record_team(batch, names, policies, record_dir, source="eval")]
    report.update({"env_id": config.env_id, "config": config.to_dict(), "episodes": episodes, "seed": seed,
                   "specs": dict(zip(config.agent_names, names))})
    first = {role: config.roles.index(role) for role in ROLES}
    report.update({role: policies[first[role]].describe() for role in ROLES})  # 1:1: the leader and the follower
    if not config.one_to_one:
        report["policies"] = {name: p.describe() for name, p in zip(config.agent_names, policies)}
    report.update({"wall_seconds": time.perf_counter() - start, "cpu_seconds": time.process_time() - cpu})
    return report


def _policy(p: str | Policy, role: str) -> Policy:
    return p if isinstance(p, Policy) else make_policy(p, role=role)


def _name(p: str | Policy) -> str:
    return p if isinstance(p, str) else getattr(p, "source", None) or p.name


def record_batch(batch, leader: str, follower: str, leader_policy, follower_policy, out_dir, source: str,
                 meta: dict | None = None) -> list[Path]:
    """A 1:1 team's ``record_team``: ``<leader>+<follower>_seed<N>.replay.json`` in ``out_dir``."""
    return record_team(batch, [leader, follower], [leader_policy, follower_policy], out_dir, source, meta)


TAG_LENGTH = 60
"""The most characters a policy's part of a replay's file name takes (``replay_tag``)."""


def replay_tag(name: str) -> str:
    """A policy's part of a replay's file name: the name with its parameters (two settings of one policy never
    share a file: ``person_slip_0.1``, ``person_slip_0.3``), a checkpoint by its file's stem (``x`` of
    ``runs/a/x.pt``, ``x_temperature_0`` of ``runs/a/x.pt:temperature=0``), in the characters a replay id allows
    (``server/replays.py``); past ``TAG_LENGTH`` cut, with a hash of the whole name after it."""
    import hashlib
    import re

    from colorgrid.policies import registry

    found = registry.file_of(name)
    text = name if found is None else Path(found).stem + name[len(found):]
    tag = re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "policy"
    if len(tag) > TAG_LENGTH:
        tag = f"{tag[:TAG_LENGTH - 9]}_{hashlib.sha256(name.encode()).hexdigest()[:8]}"
    return tag


def record_team(batch, names: Sequence[str], policies: Sequence[Policy], out_dir, source: str,
                meta: dict | None = None) -> list[Path]:
    """Save every episode of ``batch`` as ``<policy>+<policy>+..._seed<N>.replay.json`` in ``out_dir`` (one
    policy name per agent, in index order; a checkpoint's hash pins its weights)."""
    from colorgrid.replay import describe_agent, from_batch, save

    agents = {agent: describe_agent(policy.describe(), name if name.endswith(".pt") else None)
              for agent, name, policy in zip(batch.config.agent_names, names, policies)}
    tag = "+".join(replay_tag(name) for name in names)
    paths = []
    for replay in from_batch(batch, agents, source, meta=meta):
        paths.append(save(replay, Path(out_dir) / f"{tag}_seed{replay.seed}.replay.json"))
    return paths


def format_reports(reports: list[dict]) -> str:
    """A side-by-side table, one column per report (e.g. per follower, on the same seeds): per agent, then,
    beyond the 1:1 team, per role."""
    ci = format_mean_ci

    def belief(entry, key, text):
        return text(entry["belief"][key]) if "belief" in entry else "-"

    config = EnvConfig.from_dict(reports[0]["config"])
    head = [_team_label(r, config) for r in reports]
    def pickup_rows(label, entries):
        return [(f"{label} block reward", [ci(e["block_reward"]) for e in entries]),
                (f"{label} goal pickups", [f"{e['goal_pickups']['mean']:.2f}" for e in entries]),
                (f"{label} wrong pickups", [f"{e['wrong_pickups']['mean']:.2f}" for e in entries]),
                (f"{label} net pickups", [ci(e["net_pickups"]) for e in entries])]

    def belief_rows(label, entries):
        return [(f"{label} belief accuracy", [belief(e, "accuracy", "{:.1%}".format) for e in entries]),
                (f"{label} belief log-loss", [belief(e, "log_loss", "{:.3f}".format) for e in entries])]

    rows = [("team reward", [ci(r["team_reward"]) for r in reports])]
    for name in config.agent_names:
        rows += pickup_rows(name, [r["agents"][name] for r in reports])
    for i in config.followers:
        rows += belief_rows(config.agent_names[i], [r["agents"][config.agent_names[i]] for r in reports])
    rows += [("wall time", [f"{r['wall_seconds']:.2f} s" for r in reports])]
    role_rows = []
    if not config.one_to_one:
        for role in ROLES:
            label = f"{role}s ({reports[0]['roles'][role]['agents']})"
            role_rows += pickup_rows(label, [r["roles"][role] for r in reports]) + [
                (f"{label} net per agent", [ci(r["roles"][role]["net_pickups_per_agent"]) for r in reports])]
        label = f"followers ({reports[0]['roles']['follower']['agents']})"
        role_rows += belief_rows(label, [r["roles"]["follower"] for r in reports])
    labels = max(26, *(len(label) + 2 for label, _ in rows + role_rows))
    width = max(18, *(len(h) for h in head))

    def table(rows):
        return [f"{label:<{labels}}" + "".join(f"{v:>{width + 2}}" for v in values) for label, values in rows]

    lines = [f"{'':<{labels}}" + "".join(f"{h:>{width + 2}}" for h in head)] + table(rows)
    if role_rows:
        lines += ["", f"{'per role: totals over its agents, per episode':<{labels}}"] + table(role_rows)
    r0 = reports[0]
    lines.append(f"{r0['episodes']} episodes, seeds {r0['seed']}..{r0['seed'] + r0['episodes'] - 1}, {r0['env_id']}")
    return "\n".join(lines)


def _team_label(report: dict, config: EnvConfig) -> str:
    """The column head: ``astar + bayes`` for 1:1; ``astar×2 + bayes`` (or ``astar/person:slip=0.1 + bayes``) for teams. A
    policy given with parameters is named by its whole spec (``astar + shielded:mover=...,min_belief=0.8``), so that
    two columns of one kind with different parameters read apart."""
    def label(i: int) -> str:
        name = config.agent_names[i]
        spec = report.get("specs", {}).get(name, "")
        read = read_name(spec) if spec else None
        if read is not None and read.params:
            return spec
        return (report["policies"][name] if "policies" in report else report[config.roles[i]])["policy"]

    parts = []
    for role in ROLES:
        names = [label(i) for i, r in enumerate(config.roles) if r == role]
        parts.append(names[0] + (f"×{len(names)}" if len(names) > 1 else "") if len(set(names)) == 1
                     else "/".join(names))
    return " + ".join(parts)
