"""Run logs: one JSON line per record (complete), CSV per stream (fixed columns), TensorBoard scalars.

And the names of what is logged about a team: a column per agent (``follower_1_goal_pickups``)
and, beyond the 1:1 team, a column per role (its agents' sum: ``followers_goal_pickups``), for
the rollouts' finished episodes (``episode_columns``) and for evaluations (``evaluation_row``).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from colorgrid.config import ROLES, EnvConfig


class MetricsLog:
    """Writes ``metrics.jsonl``, ``<stream>.csv`` and TensorBoard events under ``run_dir``; appends on resume."""

    def __init__(self, run_dir: Path, tensorboard: bool = True):
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.jsonl = open(self.run_dir / "metrics.jsonl", "a")
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(self.run_dir / "tb"))
        self.columns: dict[str, list[str]] = {}

    def write(self, stream: str, step: int, values: dict) -> None:
        row = {"stream": stream, "step": int(step), **{k: _plain(v) for k, v in values.items()}}
        self.jsonl.write(json.dumps(row) + "\n")
        self.jsonl.flush()
        path = self.run_dir / f"{stream}.csv"
        if stream not in self.columns:
            if path.exists() and path.stat().st_size:
                with open(path) as f:
                    self.columns[stream] = next(csv.reader(f))
            else:
                self.columns[stream] = ["step", *sorted(values)]
                with open(path, "w", newline="") as f:
                    csv.writer(f).writerow(self.columns[stream])
        with open(path, "a", newline="") as f:
            csv.writer(f).writerow([row.get(c, "") for c in self.columns[stream]])
        if self.writer is not None:
            for key, value in values.items():
                if isinstance(value, (int, float)) and math.isfinite(value):
                    self.writer.add_scalar(f"{stream}/{key}", value, step)

    def close(self) -> None:
        self.jsonl.close()
        if self.writer is not None:
            self.writer.close()


def _plain(v):
    if hasattr(v, "item"):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


EPISODE_TOTALS = ("block_reward", "goal_pickups", "wrong_pickups", "net_pickups", "training_reward")
"""What the training log totals for each agent over each finished episode (``episode_totals``)."""


def episode_totals(final_info: dict, done: np.ndarray, training_reward: np.ndarray) -> dict[str, np.ndarray]:
    """Each ``EPISODE_TOTALS`` entry, ``[E, A]``, of the episodes that ended (``done``, ``[B]``): the env's episode
    records in ``final_info`` and the reward each agent trained on (``training_reward``, ``[B, A]``, shaping in)."""
    goal, wrong = final_info["episode_goal_pickups"][done], final_info["episode_wrong_pickups"][done]
    totals = {"block_reward": final_info["episode_block_reward"][done], "goal_pickups": goal,
              "wrong_pickups": wrong, "net_pickups": goal - wrong, "training_reward": training_reward[done]}
    return {key: totals[key] for key in EPISODE_TOTALS}


def episode_columns(env: EnvConfig, totals: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per-episode totals ``{metric: [E, A]}`` as columns ``{agent name}_{metric}`` (``[E]`` each), agent by agent,
    then, beyond the 1:1 team, ``{role}s_{metric}``: the sum over the role's agents."""
    out = {}
    for a, name in enumerate(env.agent_names):
        for metric, values in totals.items():
            out[f"{name}_{metric}"] = values[:, a]
    if not env.one_to_one:
        for role in ROLES:
            members = [a for a, r in enumerate(env.roles) if r == role]
            for metric, values in totals.items():
                out[f"{role}s_{metric}"] = values[:, members].sum(axis=1)
    return out


def evaluation_row(env: EnvConfig, report: dict) -> dict[str, float]:
    """An evaluation report's means (``colorgrid.evaluate.summarize``) as log columns: the team reward, each
    agent's goal, wrong and net pickups and goal-prediction accuracy (if it states a belief), then, beyond the 1:1
    team, each role's (``followers_net_pickups``: the sum over its agents; ``followers_goal_accuracy``: the mean)."""
    row = {"team_reward": report["team_reward"]["mean"]}
    sections = [(name, report["agents"][name]) for name in env.agent_names]
    if not env.one_to_one:
        sections += [(f"{role}s", report["roles"][role]) for role in ROLES]
    for name, entry in sections:
        for key in ("goal_pickups", "wrong_pickups", "net_pickups"):
            row[f"{name}_{key}"] = entry[key]["mean"]
        if "belief" in entry:
            row[f"{name}_goal_accuracy"] = entry["belief"]["accuracy"]
    return row
