"""The released replay set (``replays/``): scripted agents in the default and paper settings."""

from __future__ import annotations

from pathlib import Path

from colorgrid.policies import make_policy
from colorgrid.presets import env_config
from colorgrid.replay import load
from colorgrid.replay.index import index_entry, write_index
from colorgrid.rollout import run_episodes
from colorgrid.evaluate import record_batch

SETTINGS = {
    "default": "asymmetric, +1/-1, goal switches about 2% a step",
    "symmetric": "the follower is told the goal",
    "reward_4_1": "goal blocks pay +4, wrong ones cost 1",
    "stationary": "the goal never switches",
}
FOLLOWERS = {
    "copy": "copies the color of the leader's last paying pickup",
    "oracle": "knows the true goal (upper bound)",
    "bayes": "infers the goal with a hidden Markov model",
}
RELEASE_SEED = 2026
GIF_SETTINGS = ("default", "stationary", "reward_4_1")  # the symmetric episodes look like the default ones


def build_release(out: Path, episodes: int = 2, gifs: Path | None = None) -> list[dict]:
    """Record ``episodes`` episodes of the A* leader with each follower in each setting; write index.json and
    return its entries."""
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    for setting, setting_text in SETTINGS.items():
        config = env_config(setting)
        for follower, follower_text in FOLLOWERS.items():
            leader_policy, follower_policy = make_policy("astar"), make_policy(follower)
            batch = run_episodes(config, leader_policy, follower_policy, episodes, RELEASE_SEED, record_hashes=True)
            folder = out / setting
            paths = record_batch(batch, "astar", follower, leader_policy, follower_policy, folder, "eval",
                                 meta={"setting": setting})
            for path in paths:
                entries.append(index_entry(load(path), path.relative_to(out).as_posix(), setting=setting,
                                           description=f"A* leader with the {follower} follower ({follower_text}); "
                                                       f"{setting_text}."))
            if gifs is not None and follower == "bayes" and setting in GIF_SETTINGS:
                from colorgrid.replay.export import export

                export(load(paths[0]), gifs / f"{setting}_astar+bayes.gif", "gif", cell=8)
    write_index(out, entries, f"colorgrid replay release --out {out} --episodes {episodes}")
    return entries
