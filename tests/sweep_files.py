"""A tiny sweep file for the sweep tests (Ray's and the plain processes'): two-env, 32-step iterations."""

import time
from pathlib import Path

import pytest

TINY = """
description = "a tiny sweep"
preset = "default"
set = ["total_steps={total}", "ppo.num_envs=2", "ppo.num_steps=32", "env.horizon=32", "eval_every=0",
       "save_every={save_every}", "ppo.num_minibatches=2", "ppo.update_epochs=1", "leader.net.hidden=16",
       "follower.net.hidden=16"]
seeds = {seeds}
metric = "{metric}"
final_window = 2
{top}
{params}

[resources]
cpus_per_trial = 1
{tables}
"""


def sweep_file(tmp_path: Path, name: str, params: str, seeds="[0, 1]", total=512, save_every=2, top="",
               tables="", metric="team_reward") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(TINY.format(params=params, seeds=seeds, total=total, save_every=save_every, top=top,
                                tables=tables, metric=metric))
    return path


def wait_for_step(folder: Path, step: int, within: float = 300) -> None:
    """Wait until a trial of the sweep in ``folder`` has logged ``step`` (a bound on the wait: a loaded machine
    starts Ray and the trials slowly; not a speed)."""
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        logs = [p.read_text() for p in folder.glob("trial_*/run/metrics.jsonl")]
        if any(f'"step": {step},' in log for log in logs):
            return
        time.sleep(0.05)
    pytest.fail(f"no trial logged step {step} within {within:.0f} s")
