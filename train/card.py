"""Model cards for trained checkpoints: what was trained, how, and how it does against the baselines.

``colorgrid checkpoint card CKPT --agent follower --run RUN_DIR --command "..." --out CARD.md``
evaluates the agent with the evaluation harness (100 episodes, seeds 0..99, default config
unless the checkpoint's env differs) beside the baselines on the same seeds, and writes the
card plus the raw reports as JSON next to it.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from colorgrid.config import AGENTS, FOLLOWER, LEADER, EnvConfig
from colorgrid.evaluate import evaluate
from colorgrid.machine import cpu_name
from train.acting import ACTING
from train.checkpoint import load_checkpoint


def _row(report: dict, agent: str) -> str:
    a = report["agents"][agent]
    belief = a.get("belief")
    acc = f"{belief['accuracy']:.1%}" if belief else "-"
    ci = lambda m: f"{m['mean']:+.2f} ± {m['ci95']:.2f}"  # noqa: E731
    team = " + ".join(report[name]["policy"] for name in AGENTS)
    return (f"| {team} | {ci(report['team_reward'])} | "
            f"{a['goal_pickups']['mean']:.2f} | {a['wrong_pickups']['mean']:.2f} | {ci(a['net_pickups'])} | {acc} |")


def model_card(checkpoint: str, agent: str, run_dir: str | None, command: str, episodes: int = 100,
               seed: int = 0) -> tuple[str, dict]:
    ckpt = load_checkpoint(checkpoint)
    config = EnvConfig.from_dict(ckpt["env_config"])
    if not config.one_to_one:
        return team_card(checkpoint, ckpt, config, agent, run_dir, command, episodes, seed)
    train_cfg = ckpt["config"]
    if agent == AGENTS[FOLLOWER]:
        partner = train_cfg[AGENTS[LEADER]]["policy"]
        leader = partner if partner != "learn" else "astar"
        rows = [(leader, f) for f in ("idle", "copy", "bayes", "oracle")] + [(leader, checkpoint)]
    else:
        rows = [("astar", "idle"), (checkpoint, "idle"), (checkpoint, "bayes")]
    reports = [evaluate(config, lead, follow, episodes, seed) for lead, follow in rows]
    lines = [
        *_training_lines(checkpoint, ckpt, agent, run_dir, command),
        "- **Partner during training**: " + ", ".join(f"{name} `{train_cfg[name]['policy']}`" for name in AGENTS),
        f"- **Training settings**: PPO {json.dumps(train_cfg['ppo'])}; schedule {json.dumps(train_cfg['schedule'])}; "
        f"aux_coef {train_cfg[agent]['aux_coef']} (target `{train_cfg[agent].get('aux_target', 'goal')}`); "
        f"train_reward `{train_cfg[agent].get('train_reward', 'env')}`; "
        f"wrong_weight {train_cfg[agent].get('wrong_weight', 1.0)}",
        "- **Acting**: " + ", ".join(f"{name} {ckpt['agents'][agent].get(name, default)}"
                                     for name, (_, default) in ACTING.items()) + " (docs/EVALUATION.md)",
        f"- **Environment**: {json.dumps(ckpt['env_config'])}",
        "",
        f"## Evaluation ({episodes} episodes, seeds {seed}..{seed + episodes - 1}, the same for every row)",
        "",
        f"Figures are the {agent}'s; ± is the half-width of a 95% normal interval over episodes.",
        "",
        f"| {' + '.join(AGENTS)} | team reward | goal pickups | wrong pickups | net pickups "
        "| goal-prediction accuracy |",
        "|---|---:|---:|---:|---:|---:|",
        *(_row(r, agent) for r in reports),
        "",
        f"Reproduce: `colorgrid eval --leader {rows[-1][0]} --follower {rows[-1][1]} --episodes {episodes} "
        f"--seed {seed}`. Every action, and so every count, reproduces on another CPU too, unless a sampled "
        "uniform falls within about 1e-7 of a probability boundary; the log-loss's last float32 digits may differ "
        "(docs/TRAINING.md, \"What is exact, and where\").",
    ]
    return "\n".join(lines) + "\n", {"rows": [list(r) for r in rows], "reports": reports}


def _training_lines(checkpoint: str, ckpt: dict, agent: str, run_dir: str | None, command: str) -> list[str]:
    """The card's head: what trained it, for how long, on what, with which network."""
    train_cfg = ckpt["config"]
    wall = ckpt.get("wall_time_s")
    if wall is None and run_dir:  # checkpoints from before wall time was recorded: the run's file times
        run = Path(run_dir)
        latest = run / "checkpoints" / "latest.pt"
        if (run / "config.json").is_file() and latest.is_file():
            wall = latest.stat().st_mtime - (run / "config.json").stat().st_mtime
    return [
        f"# Model card: `{Path(checkpoint).name}` (the {agent})",
        "",
        f"- **Trained with**: `{command}`",
        f"- **Steps**: {ckpt['step']:,} env steps ({ckpt.get('iteration')} PPO iterations of "
        f"{train_cfg['ppo']['num_envs']} envs x {train_cfg['ppo']['num_steps']} steps)",
        f"- **Wall time**: {wall / 60:.0f} min ({wall:.0f} s)" if wall else "- **Wall time**: not recorded",
        f"- **Hardware**: {ckpt['device']}" if ckpt.get("device") else
        f"- **Hardware**: {cpu_name()} ({os.cpu_count()} CPUs), {train_cfg.get('threads') or 'all'} "
        f"torch thread(s), no GPU",
        f"- **Network**: {json.dumps(ckpt['agents'][agent]['net'])}",
    ]


TEAM_BASELINES = ("copy", "bayes-people", "oracle")
"""The followers a team follower's card compares it with, in the same team and on the same seeds."""


def team_card(checkpoint: str, ckpt: dict, config: EnvConfig, agent: str, run_dir: str | None, command: str,
              episodes: int, seed: int) -> tuple[str, dict]:
    """The card of a follower network trained in a team other than 1:1: every follower seat played by it, beside
    the leaders it trained with, against each of ``TEAM_BASELINES`` in every follower seat, on the same seeds."""
    if agent not in ckpt["agents"] or not agent.startswith("follower"):
        raise ValueError(f"{checkpoint}: a team card describes a follower network; this checkpoint holds "
                         f"{sorted(ckpt['agents'])}")
    train_cfg = ckpt["config"]
    leader = train_cfg["leader"]["policy"] if train_cfg["leader"]["policy"] != "learn" else "astar"
    followers = (*TEAM_BASELINES, checkpoint)
    reports = [evaluate(config, leader, follower, episodes, seed) for follower in followers]
    names = [n for n in config.agent_names if n.startswith("follower")]
    ci = lambda m: f"{m['mean']:+.2f} ± {m['ci95']:.2f}"  # noqa: E731
    team = f"{config.num_leaders}:{config.num_followers}"
    rows = []
    for name, report in zip((*TEAM_BASELINES, Path(checkpoint).name), reports):
        role = report["roles"]["follower"]
        seats = " / ".join(f"{report['agents'][n]['net_pickups']['mean']:+.2f}" for n in names)
        rows.append(f"| `{name}` | {ci(report['team_reward'])} | {ci(role['net_pickups'])} | "
                    f"{role['goal_pickups']['mean']:.2f} | {role['wrong_pickups']['mean']:.2f} | {seats} |")
    lines = [
        *_training_lines(checkpoint, ckpt, agent, run_dir, command),
        f"- **Team**: {config.num_leaders} leader(s) `{leader}` and {config.num_followers} follower(s)"
        + (", one network shared by the followers" if ckpt["agents"][agent].get("agents") and
           len(ckpt["agents"][agent]["agents"]) > 1 else ""),
        f"- **Training settings**: PPO {json.dumps(train_cfg['ppo'])}; schedule {json.dumps(train_cfg['schedule'])}; "
        f"aux_coef {train_cfg['follower']['aux_coef']}; train_reward `{train_cfg['follower'].get('train_reward')}`",
        f"- **Environment**: {json.dumps(ckpt['env_config'])}",
        "",
        f"## Evaluation in the {team} team ({episodes} episodes, seeds {seed}..{seed + episodes - 1}, the same for "
        "every row)",
        "",
        f"Every follower seat is played by the row's follower, beside {config.num_leaders} `{leader}` leader(s). "
        "Figures are per episode; ± is the half-width of a 95% normal interval over episodes; net pickups are "
        "goal minus wrong blocks.",
        "",
        f"| followers | team reward | followers' net pickups | goal pickups | wrong pickups | net per seat "
        f"({' / '.join(names)}) |",
        "|---|---:|---:|---:|---:|---:|",
        *rows,
        "",
        f"Reproduce: `colorgrid eval --team {team} --leader {leader} --compare {' '.join(followers)} "
        f"--episodes {episodes} --seed {seed}`.",
    ]
    return "\n".join(lines) + "\n", {"followers": list(followers), "reports": reports}


def write_card(checkpoint: str, agent: str, run_dir: str | None, command: str, out: str) -> Path:
    text, data = model_card(checkpoint, agent, run_dir, command)
    out_path = Path(out)
    out_path.write_text(text)
    out_path.with_suffix(".json").write_text(json.dumps(data, indent=2))
    return out_path
