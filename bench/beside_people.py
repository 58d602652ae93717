"""Every follower beside the held-out people and beside A*, against the information limit (``bayes-limit``): the
table and the picture of docs/ASSISTANT_RECIPE.md's "Beside people".

    python bench/beside_people.py measure --episodes 100 --seed 0 --workers 2 \
        --out docs/reproduction/beside_people/beside_people.json      # 388 s on 2 CPU cores beside a training run
    python bench/beside_people.py draw docs/reproduction/beside_people/beside_people.json   # the tables; the picture
    python bench/beside_people.py measure --episodes 100 --seed 0 --workers 2 --followers \
        --arms runs/sweeps/assistant_partner runs/sweeps/assistant_partners_varied \
        --add docs/reproduction/beside_people/beside_people.json --out docs/reproduction/beside_people/beside_people.json

``measure`` plays every follower beside A* and beside each member of ``population:people#held_out`` on the same
episodes (env ``i`` seeded ``seed + i``) and keeps, per episode, the follower's net and wrong pickups, its belief
accuracy and log-loss (docs/EVALUATION.md), the steps it took to catch each goal switch, and whether its belief
named the goal at each step after a switch. ``draw`` reads that file and prints the table (markdown) and draws:

- left: net pickups against wrong pickups beside the held-out people, each follower with its 95% intervals over
  episodes (each episode its own seed; the six leaders' episodes pooled, 100 seeds each);
- right: the share of goal switches whose new goal the follower's belief names, each step after the switch (95%
  bands over switches), beside the held-out people (the shipped followers; an arm is a point on the left only).

An **arm** of a sweep (``--arms FOLDER``: a sweep's run folder, its finished trials in ``trials.csv``) is one
follower made of its seeds' trained followers (each trial's last checkpoint): the ``episodes`` of each leader are
split into as many consecutive blocks as it has seeds, block ``k`` played by the ``k``-th seed's follower on the
same env seeds as every other follower. Its interval over episodes therefore holds the seed-to-seed spread too, and
its gap to the limit stays paired by episode. ``--add FILE`` keeps a report's followers and adds the new ones
(measured on the same episodes and seed, which it checks).

The gap to the limit is paired: a follower's figure minus ``bayes-limit``'s on the same episodes (mean and 95%
interval of the per-episode differences); for the steps to catch a switch, the difference of the two means, its
interval from the two intervals (their switches are the same, the catches each one's).
"""

from __future__ import annotations

import argparse
import csv
import json
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from colorgrid import EnvConfig  # noqa: E402
from colorgrid.evaluate import catch_lags  # noqa: E402
from colorgrid.policies import make_policy  # noqa: E402
from colorgrid.policies.population import load_population  # noqa: E402
from colorgrid.rollout import run_episodes  # noqa: E402
from colorgrid_apps.matrix import cpu_share, share_cpus  # noqa: E402

FOLLOWERS = ["copy", "bayes", "bayes-people", "bayes-limit", "ippo", "ippo-people", "ippo-cautious",
             "checkpoints/follower_unannealed.pt", "ippo-shielded"]
"""Every shipped follower that plays the 1:1 team: the scripted ones, the limit, each IPPO checkpoint of
``checkpoints/`` (``follower_1L2F.pt`` and ``follower_2L1F.pt`` play other teams) and the shielded follower."""
LIMIT = "bayes-limit"
HELD_OUT = "population:people#held_out"
AFTER_SWITCH = 30
"""Steps after a goal switch over which the right panel follows the belief."""


ARM = "arm:"
"""How a report names an arm of a sweep: ``arm:SWEEP/CONFIGURATION`` (``arm:assistant_partner/partner=A*``)."""


def label(follower: str) -> str:
    """A follower's name in the table and the picture (a checkpoint by its file's stem, an arm by its sweep's
    configuration)."""
    if follower.startswith(ARM):  # its sweep and its configuration's values: two sweeps may share an arm's name
        sweep, configuration = follower.removeprefix(ARM).split("/", 1)
        one = ", " not in configuration  # one parameter: its value names the arm; more: the whole configuration
        return f"{sweep}: " + (configuration.split("=", 1)[-1] if one else configuration)
    return Path(follower).stem.replace("follower_", "ippo-") if follower.endswith(".pt") else follower


def sweep_arms(folder: Path) -> dict[str, list[str]]:
    """``{arm:SWEEP/CONFIGURATION: [last checkpoint of each finished trial, in seed order]}`` for a sweep's run
    folder."""
    table = folder / "trials.csv"
    if not table.is_file():
        raise ValueError(f"--arms: {folder} has no trials.csv; give a sweep's run folder (runs/sweeps/NAME)")
    arms: dict[str, list[tuple[int, str]]] = {}
    for row in csv.DictReader(table.open()):
        if row["finished"] != "True":
            continue
        checkpoint = folder / row["trial"] / "run" / "checkpoints" / "latest.pt"
        if not checkpoint.is_file():
            raise ValueError(f"--arms: {checkpoint} is missing; rerun the sweep to make it")
        arms.setdefault(f"{ARM}{folder.name}/{row['configuration']}", []).append((int(row["seed"]), str(checkpoint)))
    if not arms:
        raise ValueError(f"--arms: {folder} has no finished trial")
    return {name: [path for _, path in sorted(seeds)] for name, seeds in arms.items()}


def cell(leader: str, follower: str | list[str], episodes: int, seed: int) -> dict:
    """One leader beside one follower: per-episode figures (lists, JSON-ready). A list of followers (an arm's
    seeds) plays the episodes in consecutive blocks, one a follower, on the same env seeds."""
    if isinstance(follower, list):
        blocks = np.array_split(np.arange(episodes), len(follower))
        parts = [cell(leader, one, len(block), seed + int(block[0])) for one, block in zip(follower, blocks)
                 if len(block)]
        kept = set.intersection(*(set(part) for part in parts))  # a belief only where every seed has one
        out = {key: sum((part[key] for part in parts), []) for key in parts[0]
               if key in kept and key not in ("after_switch", "wall_seconds")}
        if "after_switch" in kept:
            out["after_switch"] = np.sum([part["after_switch"] for part in parts], axis=0).tolist()
        out["wall_seconds"] = sum(part["wall_seconds"] for part in parts)
        return out
    try:
        import torch

        torch.set_num_threads(1)  # one process a cell
    except ImportError:  # the scripted followers need no torch
        pass
    config = EnvConfig()
    start = time.perf_counter()
    batch = run_episodes(config, make_policy(leader, "leader"), make_policy(follower, "follower"), episodes, seed)
    goal = batch.goal_pickup[:, :, 1].sum(axis=0)
    wrong = batch.wrong_pickup[:, :, 1].sum(axis=0)
    out = {"net": (goal - wrong).tolist(), "wrong": wrong.tolist(), "wall_seconds": None}
    probs = batch.goal_probs[1]
    if probs is not None:
        right = probs.argmax(axis=2) == batch.goal  # [T, B]
        truth = np.take_along_axis(probs, batch.goal[:, :, None], axis=2)[..., 0]
        out["accuracy"] = right.mean(axis=0).tolist()
        out["log_loss"] = (-np.log(np.clip(truth, 1e-6, 1.0))).mean(axis=0).tolist()
        out["lags"] = catch_lags(right, batch.goal).tolist()
        out["after_switch"] = after_switch(right, batch.goal, AFTER_SWITCH).tolist()
    out["wall_seconds"] = time.perf_counter() - start
    return out


def after_switch(right: np.ndarray, goal: np.ndarray, steps: int) -> np.ndarray:
    """``[2, steps + 1]``: over every goal switch, how many times the belief was right ``k`` steps after it (row 0)
    and how many switches were still followed then (row 1: the new goal still held and the episode went on).

    right, goal: ``[T, B]``; step ``t`` is the first with the new goal when ``goal[t] != goal[t - 1]``; ``k = 0``
    is that step."""
    T, B = goal.shape
    counts = np.zeros((2, steps + 1), dtype=np.int64)
    for t, e in zip(*np.nonzero(goal[1:] != goal[:-1])):
        t += 1
        for k in range(steps + 1):
            if t + k >= T or goal[t + k, e] != goal[t, e]:
                break
            counts[0, k] += int(right[t + k, e])
            counts[1, k] += 1
    return counts


def measure(followers: list[str], episodes: int, seed: int, workers: int,
            arms: dict[str, list[str]] | None = None) -> dict:
    """Every follower (and each arm, its seeds' checkpoints) beside A* and each held-out leader."""
    arms = arms or {}
    leaders = {"astar": "astar", **load_population(HELD_OUT.removeprefix("population:"))}
    followers = [*followers, *arms]
    jobs = [(name, follower) for name in leaders for follower in followers]
    start = time.perf_counter()
    args = [(leaders[n], arms.get(f, f), episodes, seed) for n, f in jobs]
    if workers == 1:
        results = [cell(*a) for a in args]
    else:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=share_cpus,
                                 initargs=(cpu_share(workers),)) as pool:
            results = list(pool.map(cell, *zip(*args)))
    cells = {name: {} for name in leaders}
    for (name, follower), result in zip(jobs, results):
        cells[name][follower] = result
    return {"episodes": episodes, "seed": seed, "leaders": leaders, "held_out": [n for n in leaders if n != "astar"],
            "followers": followers, "arms": arms, "cells": cells, "wall_seconds": time.perf_counter() - start}


def same_episodes(kept: dict, **measure) -> None:
    """Refuse, in one line, a measure (its episodes, seed, leaders: whichever are given) not played on ``kept``'s
    episodes."""
    for key, value in measure.items():
        if kept[key] != value:
            raise ValueError(f"--add: the kept report has {key} {kept[key]!r}, this measure {value!r}; "
                             "measure with the kept report's --episodes and --seed")


def merge(kept: dict, new: dict) -> dict:
    """``kept`` with ``new``'s followers added (replaced where both have one); both on the same episodes."""
    same_episodes(kept, episodes=new["episodes"], seed=new["seed"], leaders=new["leaders"])
    followers = [f for f in kept["followers"] if f not in new["followers"]] + new["followers"]
    cells = {name: {**kept["cells"][name], **new["cells"][name]} for name in kept["cells"]}
    return {**kept, "followers": followers, "arms": {**kept.get("arms", {}), **new["arms"]}, "cells": cells,
            "wall_seconds": kept["wall_seconds"] + new["wall_seconds"]}


def mean_ci(values) -> tuple[float, float]:
    """Mean and the half-width of its 95% normal interval."""
    values = np.asarray(values, dtype=np.float64)
    half = 1.96 * values.std(ddof=1) / np.sqrt(values.size) if values.size > 1 else float("nan")
    return float(values.mean()), float(half)


def pooled(report: dict, leaders: list[str], follower: str, key: str) -> np.ndarray | None:
    """The per-episode ``key`` of ``follower`` beside ``leaders``, in leader then seed order (None: no belief)."""
    cells = [report["cells"][n][follower] for n in leaders]
    if key not in cells[0]:
        return None
    return np.concatenate([np.asarray(c[key], dtype=np.float64) for c in cells])


def summary(report: dict, leaders: list[str]) -> dict:
    """Per follower beside ``leaders``: each measure's (mean, half-width), and its gap to the limit (paired)."""
    out = {}
    for follower in report["followers"]:
        row = {}
        for key in ("net", "wrong", "accuracy", "log_loss", "lags"):
            values = pooled(report, leaders, follower, key)
            row[key] = None if values is None else mean_ci(values)
        gap = {}
        if LIMIT in report["followers"] and follower != LIMIT:
            for key in ("net", "wrong", "accuracy", "log_loss"):
                mine, limit = pooled(report, leaders, follower, key), pooled(report, leaders, LIMIT, key)
                gap[key] = None if mine is None else mean_ci(mine - limit)
            limit_lag = row["lags"] is not None and summary_lag(report, leaders, LIMIT)
            gap["lags"] = None if not limit_lag else (row["lags"][0] - limit_lag[0],
                                                      float(np.hypot(row["lags"][1], limit_lag[1])))
        row["gap"] = gap
        out[follower] = row
    return out


def summary_lag(report: dict, leaders: list[str], follower: str) -> tuple[float, float]:
    return mean_ci(pooled(report, leaders, follower, "lags"))


def fmt(pair, form: str = "{:+.2f}", scale: float = 1.0) -> str:
    if pair is None:
        return "-"
    mean, half = pair[0] * scale, pair[1] * scale
    return f"{form.format(mean)} ± {form.format(half).lstrip('+')}"


def table(report: dict, leaders: list[str]) -> str:
    """The markdown table: each follower's measures beside ``leaders`` and its gap to the limit."""
    rows = summary(report, leaders)
    lines = ["| follower | net pickups | wrong pickups | belief accuracy | log-loss | steps to catch a switch "
             "| gap to the limit: net | accuracy | log-loss | steps to catch |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for follower, row in rows.items():
        gap = row["gap"]
        if follower == LIMIT:
            gaps = ["(the limit)", "", "", ""]
        elif not gap:  # the limit was not measured
            gaps = ["-"] * 4
        else:
            gaps = [fmt(gap.get("net")), fmt(gap.get("accuracy"), "{:+.1f}", 100), fmt(gap.get("log_loss"), "{:+.3f}"),
                    fmt(gap.get("lags"), "{:+.2f}")]
        lines.append(" | ".join([
            f"| `{label(follower)}`", fmt(row["net"]), fmt(row["wrong"], "{:.2f}"),
            fmt(row["accuracy"], "{:.1f}%", 100), fmt(row["log_loss"], "{:.3f}"), fmt(row["lags"], "{:.2f}"),
            *gaps]) + " |")
    return "\n".join(lines)


def per_leader(report: dict) -> str:
    """The markdown table of each follower's gap to the limit beside each held-out leader: net pickups, and belief
    accuracy in points (paired over that leader's episodes)."""
    followers = [f for f in report["followers"] if f != LIMIT]
    lines = ["| leader | limit: net / accuracy | " + " | ".join(f"`{label(f)}`" for f in followers) + " |",
             "|---|---:|" + "---:|" * len(followers)]
    for name in report["held_out"]:
        limit = summary(report, [name])[LIMIT]
        cells = []
        for follower in followers:
            gap = summary(report, [name])[follower]["gap"]
            acc = "" if gap["accuracy"] is None else f" / {gap['accuracy'][0] * 100:+.1f}"
            cells.append(f"{gap['net'][0]:+.2f}{acc}")
        lines.append(f"| {name} | {limit['net'][0]:+.2f} / {limit['accuracy'][0]:.1%} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def draw(report: dict, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    leaders = report["held_out"]
    rows = summary(report, leaders)
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.8))
    shipped, arms = [f for f in rows if not f.startswith(ARM)], [f for f in rows if f.startswith(ARM)]
    palette = {**{f: plt.get_cmap("tab10")(i % 10) for i, f in enumerate(shipped)},
               **{f: plt.get_cmap("Dark2")(i % 8) for i, f in enumerate(arms)}}
    names, arm_marks = [], []
    for follower, row in rows.items():
        (net, net_ci), (wrong, wrong_ci) = row["net"], row["wrong"]
        marker = ("*" if follower == LIMIT else "s" if follower.startswith(("bayes", "copy"))
                  else "D" if follower.startswith(ARM) else "o")
        mark = left.errorbar(wrong, net, xerr=wrong_ci, yerr=net_ci, fmt=marker, color=palette[follower], capsize=3,
                             markersize=11 if marker == "*" else 7, label=label(follower))
        if follower.startswith(ARM):  # the arms crowd one corner: a legend names them
            arm_marks.append(mark)
        else:
            names.append(left.annotate(label(follower), (wrong, net), textcoords="offset points", xytext=(6, 5),
                                       fontsize=8))
        if row["accuracy"] is None or follower.startswith(ARM):  # the right panel: shipped followers only
            continue
        counts = sum(np.asarray(report["cells"][n][follower]["after_switch"]) for n in leaders)
        steps = np.arange(counts.shape[1])
        share = counts[0] / np.maximum(counts[1], 1)
        half = 1.96 * np.sqrt(share * (1 - share) / np.maximum(counts[1], 1))
        right.plot(steps, share, color=palette[follower], label=label(follower), lw=2.2 if follower == LIMIT else 1.4,
                   ls="--" if follower == LIMIT else "-")
        right.fill_between(steps, share - half, share + half, color=palette[follower], alpha=0.12)
    left.margins(x=0.15, y=0.08)  # room for the names beside the outermost points
    left.set_xlabel("wrong pickups per episode")
    left.set_ylabel("net pickups per episode (goal - wrong)")
    left.set_title(f"Beside the held-out people ({len(leaders)} leaders x {report['episodes']} seeds)", fontsize=10)
    left.grid(alpha=0.3)
    if arm_marks:
        left.legend(handles=arm_marks, title="sweep arms (diamonds)", fontsize=7, title_fontsize=7, loc="lower left")
    right.set_xlabel("steps after a goal switch")
    right.set_ylabel("share of switches whose new goal the belief names")
    right.set_title("Catching a switch, beside the held-out people (95% bands)", fontsize=10)
    right.set_ylim(0, 1)
    right.grid(alpha=0.3)
    right.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    keep_apart(fig, names)
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)


def keep_apart(fig, names) -> None:
    """Move each point's name to the first of four places beside it (right above, right below, left above, left
    below) where it stays inside its axes and overlaps no name placed before it."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    placed = []
    for name in names:
        frame = name.axes.get_window_extent(renderer)
        for offset, align in (((6, 5), "left"), ((6, -12), "left"), ((-6, 5), "right"), ((-6, -12), "right")):
            name.set_position(offset)
            name.set_horizontalalignment(align)
            box = name.get_window_extent(renderer)
            inside = frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
            if inside and not any(box.overlaps(other) for other in placed):
                break
        placed.append(name.get_window_extent(renderer))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("measure", help="play every follower beside A* and the held-out people; write JSON")
    run.add_argument("--episodes", type=int, default=100)
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--followers", nargs="*", default=FOLLOWERS, help="policy names (none: the arms alone)")
    run.add_argument("--arms", nargs="+", type=Path, default=[], metavar="FOLDER",
                     help="sweep run folders: each configuration an arm of its seeds' trained followers")
    run.add_argument("--add", type=Path, help="a report to keep, the new followers added to it")
    run.add_argument("--workers", type=int, default=1, help="processes for the cells (the result is the same)")
    run.add_argument("--out", type=Path, required=True)
    pic = sub.add_parser("draw", help="print the table and draw the picture from measure's JSON")
    pic.add_argument("json", type=Path)
    pic.add_argument("--png", type=Path, default=ROOT / "docs" / "images" / "beside_people.png")
    args = parser.parse_args(argv)
    if args.command == "measure":
        if args.episodes < 2:
            parser.error(f"--episodes must be >= 2 (an interval needs two), got {args.episodes}")
        try:
            arms = {name: paths for folder in args.arms for name, paths in sweep_arms(folder).items()}
            if not args.followers and not arms:
                raise ValueError("nothing to measure: give --followers, --arms or both")
            kept = json.loads(args.add.read_text()) if args.add else None
            if kept is not None:
                same_episodes(kept, episodes=args.episodes, seed=args.seed)  # before the minutes of play
            report = measure(args.followers, args.episodes, args.seed, args.workers, arms)
            if kept is not None:
                report = merge(kept, report)
        except (ValueError, OSError) as error:
            parser.error(str(error))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report))
        print(f"wrote {args.out} ({report['wall_seconds']:.0f} s)")
        return 0
    report = json.loads(args.json.read_text())
    print(f"Beside the held-out people ({', '.join(report['held_out'])}; {report['episodes']} episodes each, "
          f"seeds {report['seed']}..{report['seed'] + report['episodes'] - 1}):\n")
    print(table(report, report["held_out"]))
    print(f"\nBeside A* ({report['episodes']} episodes):\n")
    print(table(report, ["astar"]))
    if LIMIT in report["followers"]:
        print("\nGap to the limit beside each held-out leader: net pickups / belief accuracy (points)\n")
        print(per_leader(report))
    draw(report, args.png)
    print(f"\nwrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
