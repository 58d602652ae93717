"""The evaluation harness: metrics over a batch of episodes, as a table and as JSON."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from colorgrid.config import AGENTS, ENV_ID, EnvConfig
from colorgrid.policies import Policy, make_policy
from colorgrid.rollout import EpisodeBatch, run_episodes


def mean_ci(values: np.ndarray) -> dict:
    """Mean and the half-width of its 95% normal confidence interval."""
    values = np.asarray(values, dtype=np.float64)
    n = values.size
    half = 1.96 * values.std(ddof=1) / np.sqrt(n) if n > 1 else float("nan")
    return {"mean": float(values.mean()), "ci95": float(half)}


def summarize(batch: EpisodeBatch) -> dict:
    """Per-agent and team metrics of a batch of episodes (see docs/EVALUATION.md)."""
    agents = {}
    for i, name in enumerate(AGENTS):
        goal = batch.goal_pickup[:, :, i].sum(axis=0)
        wrong = batch.wrong_pickup[:, :, i].sum(axis=0)
        entry = {
            "block_reward": mean_ci(batch.block_reward[:, :, i].sum(axis=0)),
            "goal_pickups": mean_ci(goal),
            "wrong_pickups": mean_ci(wrong),
            "net_pickups": mean_ci(goal - wrong),
        }
        probs = batch.goal_probs[i]
        if probs is not None:
            truth = np.take_along_axis(probs, batch.goal[:, :, None], axis=2)[..., 0]  # [T, B]
            entry["belief"] = {
                "accuracy": float((probs.argmax(axis=2) == batch.goal).mean()),
                "log_loss": float(-np.log(np.clip(truth, 1e-6, 1.0)).mean()) + 0.0,
            }
        agents[name] = entry
    return {
        "agents": agents,
        "team_reward": mean_ci(batch.team_reward.sum(axis=0)),
        "goal_switches_per_episode": float(batch.goal_switched.sum(axis=0).mean()),
    }


def switch_lags(goal_probs: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Steps from each goal switch until the belief's argmax names the new goal.

    goal_probs: [T, B, C] beliefs when acting; goal: [T, B] true goal at those steps.
    Switches followed by another switch (or the episode end) before the belief
    catches up are left out.
    """
    T, B = goal.shape
    lags = []
    for e in range(B):
        for t in range(1, T):
            if goal[t, e] == goal[t - 1, e]:
                continue
            k = 0
            while t + k < T and goal[t + k, e] == goal[t, e] and goal_probs[t + k, e].argmax() != goal[t, e]:
                k += 1
            if t + k < T and goal[t + k, e] == goal[t, e]:
                lags.append(k)
    return np.array(lags, dtype=np.int64)


def evaluate(config: EnvConfig, leader: str | Policy, follower: str | Policy, episodes: int, seed: int,
             record_dir: str | Path | None = None) -> dict:
    """Run ``episodes`` episodes (env i seeded ``seed + i``) and summarize them.

    ``leader`` and ``follower`` are policy names (scripted or ``.pt`` checkpoints) or
    ``Policy`` objects. With ``record_dir``, every episode is also saved there as a replay.
    """
    start, cpu = time.perf_counter(), time.process_time()
    leader_policy, follower_policy = _policy(leader, "leader"), _policy(follower, "follower")
    leader, follower = _name(leader), _name(follower)
    batch = run_episodes(config, leader_policy, follower_policy, episodes, seed, record_hashes=record_dir is not None)
    report = summarize(batch)
    if record_dir is not None:
        report["replays"] = [str(p) for p in record_batch(batch, leader, follower, leader_policy, follower_policy,
                                                           record_dir, source="eval")]
    report.update({
        "env_id": ENV_ID, "config": config.to_dict(), "episodes": episodes, "seed": seed,
        "leader": leader_policy.describe(), "follower": follower_policy.describe(),
        "wall_seconds": time.perf_counter() - start, "cpu_seconds": time.process_time() - cpu,
    })
    return report


def _policy(p: str | Policy, role: str) -> Policy:
    return p if isinstance(p, Policy) else make_policy(p, role=role)


def _name(p: str | Policy) -> str:
    return p if isinstance(p, str) else getattr(p, "source", None) or p.name


def record_batch(batch, leader: str, follower: str, leader_policy, follower_policy, out_dir, source: str,
                 meta: dict | None = None) -> list[Path]:
    """Save every episode of ``batch`` as ``<leader>+<follower>_seed<N>.replay.json`` in ``out_dir``."""
    from colorgrid.replay import describe_agent, from_batch, save

    agents = {
        "leader": describe_agent(leader_policy.describe(), leader if leader.endswith(".pt") else None),
        "follower": describe_agent(follower_policy.describe(), follower if follower.endswith(".pt") else None),
    }
    tag = f"{Path(leader).stem}+{Path(follower).stem}"
    paths = []
    for replay in from_batch(batch, agents, source, meta=meta):
        paths.append(save(replay, Path(out_dir) / f"{tag}_seed{replay.seed}.replay.json"))
    return paths


def format_reports(reports: list[dict]) -> str:
    """A side-by-side table, one column per report (e.g. per follower, on the same seeds)."""
    def ci(m):
        return f"{m['mean']:+.2f} ± {m['ci95']:.2f}"

    head = [f"{r['leader']['policy']} + {r['follower']['policy']}" for r in reports]
    rows = [("team reward", [ci(r["team_reward"]) for r in reports])]
    for name in AGENTS:
        rows += [
            (f"{name} block reward", [ci(r["agents"][name]["block_reward"]) for r in reports]),
            (f"{name} goal pickups", [f"{r['agents'][name]['goal_pickups']['mean']:.2f}" for r in reports]),
            (f"{name} wrong pickups", [f"{r['agents'][name]['wrong_pickups']['mean']:.2f}" for r in reports]),
            (f"{name} net pickups", [ci(r["agents"][name]["net_pickups"]) for r in reports]),
        ]
    rows += [
        ("follower belief accuracy", [f"{r['agents']['follower']['belief']['accuracy']:.1%}"
                                      if "belief" in r["agents"]["follower"] else "-" for r in reports]),
        ("follower belief log-loss", [f"{r['agents']['follower']['belief']['log_loss']:.3f}"
                                      if "belief" in r["agents"]["follower"] else "-" for r in reports]),
        ("wall time", [f"{r['wall_seconds']:.2f} s" for r in reports]),
    ]
    width = max(18, *(len(h) for h in head))
    lines = [f"{'':<26}" + "".join(f"{h:>{width + 2}}" for h in head)]
    lines += [f"{label:<26}" + "".join(f"{v:>{width + 2}}" for v in values) for label, values in rows]
    r0 = reports[0]
    lines.append(f"{r0['episodes']} episodes, seeds {r0['seed']}..{r0['seed'] + r0['episodes'] - 1}, {r0['env_id']}")
    return "\n".join(lines)
