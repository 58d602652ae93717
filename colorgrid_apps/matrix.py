"""Followers judged across a population of leaders: a leader x follower matrix and paired differences.

Every (leader, follower) pair plays the same episodes (env ``i`` seeded ``seed + i``), so two
followers beside one leader face the same boards and goal switches: their difference per
episode is a paired sample, and its 95% interval is much tighter than the two means' own.
A person-like leader's own random draws (slips, detours) come from one generator per policy,
drawn for the whole batch each step: they are the same for two followers only while the
episodes unfold alike, so the pairing is exact for the environment and close, not exact, for
the leader's randomness (the interval stays valid; it is a little wider than it could be).
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from colorgrid.config import ENV_ID, FOLLOWER, EnvConfig
from colorgrid.evaluate import mean_ci, switch_lags
from colorgrid.policies import make_policy
from colorgrid.policies.names import PolicyKind, read_name
from colorgrid.policies.population import load_population
from colorgrid.rollout import run_episodes


def cell(config: EnvConfig, leader: str, follower: str, episodes: int, seed: int) -> tuple[dict, np.ndarray]:
    """The metrics of one pair, and the follower's net pickups per episode ``[episodes]``."""
    batch = run_episodes(config, make_policy(leader, "leader"), make_policy(follower, "follower"), episodes, seed)
    goal = batch.goal_pickup[:, :, FOLLOWER].sum(axis=0)
    wrong = batch.wrong_pickup[:, :, FOLLOWER].sum(axis=0)
    probs = batch.goal_probs[FOLLOWER]
    metrics = {
        "net_pickups": mean_ci(goal - wrong), "goal_pickups": mean_ci(goal), "wrong_pickups": mean_ci(wrong),
        "team_reward": mean_ci(batch.team_reward.sum(axis=0)),
        "belief_accuracy": None if probs is None else float((probs.argmax(axis=2) == batch.goal).mean()),
        "steps_to_catch_a_switch": None,
    }
    if probs is not None:
        lags = switch_lags(probs, batch.goal)
        metrics["steps_to_catch_a_switch"] = float(np.median(lags)) if lags.size else None
    return metrics, (goal - wrong).astype(np.float64)


def evaluate_matrix(config: EnvConfig, leaders: dict[str, str], followers: list[str], episodes: int,
                    seed: int, workers: int | None = None, address: str | None = None) -> dict:
    """``leaders`` (name -> policy spec) x ``followers``; paired differences against the first follower.

    Cells run in ``workers`` processes (default: one per CPU), or, with ``address``, as Ray tasks of one
    CPU each on the Ray cluster there (``auto``: the one this machine belongs to; a Ray already started
    in this process is used as it is). Each cell is seeded the same whatever process runs it, so the
    result depends on neither.
    """
    start = time.perf_counter()
    pairs = [(name, follower) for name in leaders for follower in followers]
    workers = max(1, min(workers or os.cpu_count() or 1, len(pairs)))
    if address:
        results = ray_cells(address, [(config, leaders[n], f, episodes, seed) for n, f in pairs])
    elif workers == 1:
        results = [cell(config, leaders[n], f, episodes, seed) for n, f in pairs]
    else:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=share_cpus,
                                 initargs=(cpu_share(workers),)) as pool:
            results = list(pool.map(cell, *zip(*[(config, leaders[n], f, episodes, seed) for n, f in pairs])))
    cells, per_episode = {name: {} for name in leaders}, {}
    for (name, follower), (metrics, nets) in zip(pairs, results):
        cells[name][follower], per_episode[name, follower] = metrics, nets
    base = followers[0]
    paired = {f: {name: mean_ci(per_episode[name, f] - per_episode[name, base]) for name in leaders}
              for f in followers[1:]}
    overall = {f: {"net_pickups": float(np.mean([cells[n][f]["net_pickups"]["mean"] for n in leaders])),
                   "wrong_pickups": float(np.mean([cells[n][f]["wrong_pickups"]["mean"] for n in leaders]))}
               for f in followers}
    return {"env_id": ENV_ID, "config": config.to_dict(), "episodes": episodes, "seed": seed,
            "leaders": leaders, "followers": followers, "cells": cells, "baseline": base,
            "paired_difference": paired, "mean_over_leaders": overall,
            "workers": None if address else workers, "ray_address": address,
            "wall_seconds": time.perf_counter() - start}


def cpu_share(workers: int) -> int:
    """Each of ``workers`` processes' share of this machine's CPUs: at least one."""
    return max(1, (os.cpu_count() or 1) // workers)


def share_cpus(threads: int) -> None:
    """A pool worker's torch computes on ``threads`` threads, its share of the CPUs (as a Ray task of one CPU gets
    ``OMP_NUM_THREADS=1``): torch's default of a thread per core in each of several workers would put several
    threads on every core, where they spin waiting for each other (docs/PERFORMANCE.md, "torch's threads beside
    other work"). Set for the torch a cell imports later; a scripted-only matrix never imports it."""
    os.environ["OMP_NUM_THREADS"] = str(threads)
    if "torch" in sys.modules:  # already imported by the main module the worker ran first
        sys.modules["torch"].set_num_threads(threads)


def ray_cells(address: str, jobs: list[tuple]) -> list:
    """Every cell as a Ray task (one CPU each) on the cluster at ``address``, in order."""
    from colorgrid.extras import require

    require("sweep", "--address (the cells as Ray tasks)", only=("ray",))
    import ray

    if not ray.is_initialized():
        ray.init(address=address, logging_level="WARNING", log_to_driver=False)
    task = ray.remote(num_cpus=1)(cell)
    return ray.get([task.remote(*job) for job in jobs])


def leaders_from(spec: str) -> dict[str, str]:
    """A population (``FILE[#PART]`` or ``population:NAME[#PART]``) or one policy spec, as name -> spec."""
    name = read_name(spec)
    if name is not None and name.kind is PolicyKind.POPULATION:
        return load_population(name.target)
    return {spec: spec}


def format_matrix(report: dict) -> str:
    """The matrix as text: net pickups (± 95%), wrong pickups, belief accuracy and lag per cell; then paired
    differences against the first follower."""
    followers, cells = report["followers"], report["cells"]
    width = max(26, *(len(f) + 2 for f in followers))
    out = [f"follower net pickups ± 95% / wrong pickups / belief accuracy / median steps to catch a switch",
           f"{'leader':<16}" + "".join(f"{f:>{width}}" for f in followers)]
    for name, row in cells.items():
        texts = []
        for f in followers:
            m = row[f]
            acc = "-" if m["belief_accuracy"] is None else f"{m['belief_accuracy']:.0%}"
            lag = "-" if m["steps_to_catch_a_switch"] is None else f"{m['steps_to_catch_a_switch']:.0f}"
            texts.append(f"{m['net_pickups']['mean']:+.1f}±{m['net_pickups']['ci95']:.1f} / "
                         f"{m['wrong_pickups']['mean']:.1f} / {acc} / {lag}")
        out.append(f"{name:<16}" + "".join(f"{t:>{width}}" for t in texts))
    means = report["mean_over_leaders"]
    out.append(f"{'mean':<16}" + "".join(f"{means[f]['net_pickups']:>+{width - 8}.2f} / {means[f]['wrong_pickups']:.1f}  "
                                         for f in followers))
    if report["paired_difference"]:
        out.append(f"\npaired difference in follower net pickups against {report['baseline']} (same seeds), ± 95%")
        out.append(f"{'leader':<16}" + "".join(f"{f:>{width}}" for f in report["paired_difference"]))
        for name in cells:
            out.append(f"{name:<16}" + "".join(
                f"{d[name]['mean']:>+{width - 7}.2f} ± {d[name]['ci95']:.2f}" for d in report["paired_difference"].values()))
    out.append(f"{report['episodes']} episodes per cell, seeds {report['seed']}..{report['seed'] + report['episodes'] - 1}, "
               f"{report['env_id']}, {report['wall_seconds']:.0f} s")
    return "\n".join(out)
