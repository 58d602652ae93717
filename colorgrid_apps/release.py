"""The released replay set (``replays/``): scripted agents in the default and paper settings, and the recipe
ablation's trained followers beside the A* leader (docs/ASSISTANT_RECIPE.md), one replay per arm."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

from colorgrid.config import EnvConfig
from colorgrid.extras import require
from colorgrid.policies import make_policy, policy_card
from colorgrid.presets import env_config
from colorgrid.replay import describe_agent, from_batch, load, save
from colorgrid.replay.index import index_entry, read_index, write_index
from colorgrid.rollout import run_episodes
from colorgrid.evaluate import record_batch

SETTINGS = {
    "default": "asymmetric, +1/-1, goal switches about 2% a step",
    "symmetric": "the follower is told the goal",
    "reward_4_1": "goal blocks pay +4, wrong ones cost 1",
    "stationary": "the goal never switches",
}
FOLLOWERS = ("copy", "oracle", "bayes")
"""The followers released beside the A* leader, each described by its card's summary (``PolicyCard.summary``)."""
RELEASE_SEED = 2026
GIF_SETTINGS = ("default", "stationary", "reward_4_1")  # the symmetric episodes look like the default ones
RECIPE_SETTING = "assistant_recipe"
"""The recipe ablation's replays: their setting, and their folder in the release."""
RECIPE_SEED = 0
"""The training seed whose trial gives each arm its released follower."""
TRIAL_CHECKPOINT = Path("run", "checkpoints", "latest.pt")
"""A trial's last checkpoint, in its folder (a resumable trainer checkpoint: its networks are policies)."""


@dataclass(frozen=True)
class RecipeTrial:
    """The seed-0 trial of one arm of the recipe ablation, trained to its last step."""

    arm: str
    folder: Path
    """The trial's folder in the sweep's folder (``params.json``, the training run in ``run/``)."""
    env: EnvConfig
    """The environment it trained in (its ``run/config.json``): its replay is played in it."""
    step: int
    """The step of its last checkpoint (``run/checkpoints/latest.pt``), the run's last."""

    @property
    def checkpoint(self) -> Path:
        return self.folder / TRIAL_CHECKPOINT


@dataclass(frozen=True)
class RecipeSweep:
    """What a recipe ablation's sweep folder gives the release: each arm's finished seed-0 trial, in the sweep
    file's order, and one line for each arm whose seed-0 trial has not finished."""

    folder: Path
    finished: tuple[RecipeTrial, ...]
    skipped: tuple[str, ...]


def arm_slug(arm: str) -> str:
    """An arm's name in file names: ``LSTM without last-step inputs`` -> ``lstm-without-last-step-inputs``."""
    return re.sub(r"[^a-z0-9-]", "", arm.lower().replace(" ", "-"))


def recipe_file(arm: str) -> str:
    """An arm's replay in the release, relative to its folder."""
    return f"{RECIPE_SETTING}/{arm_slug(arm)}_seed{RELEASE_SEED}.replay.json"


def recipe_arms(spec, folder: Path) -> tuple[str, ...]:
    """The arms of a sweep (``train.sweep.spec.SweepSpec``) whose trials vary the arm alone, each with a file name
    of its own; else ``ValueError``."""
    if spec.param_names != ["arm"]:
        raise ValueError(f"{folder}: not a recipe ablation (its trials vary {spec.param_names or 'nothing'}, not the "
                         f"arm alone)")
    arms = tuple(spec.params[0].values)
    slugs: dict[str, str] = {}
    for arm in arms:
        if not arm_slug(arm) or arm_slug(arm) in slugs:
            raise ValueError(f"{folder}: the arm {arm!r} has no file name of its own ({arm_slug(arm)!r}"
                             + (f", as {slugs[arm_slug(arm)]!r} has" if arm_slug(arm) in slugs else "") + ")")
        slugs[arm_slug(arm)] = arm
    return arms


def read_recipe_sweep(folder: Path) -> RecipeSweep:
    """The recipe ablation's sweep folder (``colorgrid sweep run sweeps/assistant_recipe.toml`` makes it, with or
    without ``--local``): a trial has finished when its training log (``run/metrics.jsonl``) reaches the run's
    last step and its checkpoint is of that step. A folder that is not a sweep's, or a sweep whose trials vary
    more than the arm, is refused (``ValueError``)."""
    what = "colorgrid replay release --recipe"
    require("train", what, only=("torch",))
    require("sweep", what, only=("pandas",))
    from train.checkpoint import load_checkpoint
    from train.cli import resumed_config
    from train.sweep.results import committed_keys, finished, results_folder, trained_to
    from train.sweep.spec import load_folder

    spec = load_folder(folder)  # a SweepError (a ValueError) when it is not a sweep's folder
    arms = recipe_arms(spec, folder)
    trials, params = {}, {}
    for params_file in sorted(folder.glob("trial_*/params.json")):
        values = json.loads(params_file.read_text())
        if int(values.get("seed", -1)) == RECIPE_SEED:
            trials[values.get("arm")], params[values.get("arm")] = params_file.parent, values
    kept = committed_keys(spec, folder)  # trials run elsewhere: their results kept with the project, not their runs
    ready, skipped = [], []
    for arm in arms:
        trial = trials.get(arm)
        if trial is None and (spec.label({"arm": arm}), RECIPE_SEED) in kept:
            skipped.append(f"skipped the arm '{arm}': its seed-{RECIPE_SEED} trial finished elsewhere (its results "
                           f"are kept in {results_folder(spec, folder)}); its checkpoint is not in {folder}")
            continue
        run = trial / "run" if trial is not None else None
        if run is None or not (run / "config.json").is_file():
            skipped.append(f"skipped the arm '{arm}': its seed-{RECIPE_SEED} trial has not started in {folder}")
            continue
        config = resumed_config(run, [])
        total = config.end_step
        step = load_checkpoint(trial / TRIAL_CHECKPOINT)["step"] if finished(spec, trial, params[arm]) \
            else trained_to(trial)
        if step < total:
            skipped.append(f"skipped the arm '{arm}': its seed-{RECIPE_SEED} trial ({trial.name}) has not finished "
                           f"(step {step:,} of {total:,})")
            continue
        ready.append(RecipeTrial(arm, trial, config.env, step))
    return RecipeSweep(folder, tuple(ready), tuple(skipped))


def steps_text(steps: int) -> str:
    """``3,000,320`` -> ``3M``, ``4,096`` -> ``4.1k``."""
    for size, unit in ((1_000_000, "M"), (1_000, "k")):
        if steps >= size:
            return f"{steps / size:.2g}{unit}"
    return str(steps)


def record_recipe(out: Path, trial: RecipeTrial, sweep: Path) -> dict:
    """The arm's follower (its trial's last checkpoint, acting as it trained) beside the A* leader in the trial's
    environment, on the release seed: the replay written to ``out/recipe_file(arm)``, and its index entry. The
    follower's policy is named after the arm (``ippo [no memory]``): the replay list shows it."""
    leader, follower = make_policy("astar"), make_policy(str(trial.checkpoint), role="follower")
    follower.name = f"ippo [{trial.arm}]"
    batch = run_episodes(trial.env, leader, follower, 1, RELEASE_SEED, record_hashes=True)
    agents = {name: describe_agent(policy.describe())
              for name, policy in zip(trial.env.agent_names, (leader, follower))}
    origin = {"arm": trial.arm, "sweep": sweep.as_posix(), "trial": trial.folder.name, "step": trial.step}
    [replay] = from_batch(batch, agents, "eval", meta={"setting": RECIPE_SETTING, **origin})
    file = recipe_file(trial.arm)
    save(replay, out / file)
    env = trial.env
    rewards = f"+{env.goal_reward:g}/-{env.wrong_penalty:g}"
    setting = f"asymmetric, {rewards}, goal hidden" if env.asymmetric else f"symmetric, {rewards}, goal shown"
    description = (f"The recipe ablation's '{trial.arm}' follower (seed {RECIPE_SEED}, {steps_text(trial.step)} "
                   f"steps) beside the A* leader; {setting} (docs/ASSISTANT_RECIPE.md).")
    return index_entry(load(out / file), file, description, setting=RECIPE_SETTING, **origin)


def recipe_entries(out: Path, recipe: RecipeSweep | None) -> list[dict]:
    """The recipe replays' index entries: those of ``out``'s index whose file is there, with each finished arm of
    ``recipe`` recorded (again) in place of its earlier entry."""
    entries = {e["file"]: e for e in read_index(out)
               if e.get("setting") == RECIPE_SETTING and e["file"].startswith(f"{RECIPE_SETTING}/")
               and (out / e["file"]).is_file()}
    for trial in recipe.finished if recipe is not None else ():
        entry = record_recipe(out, trial, recipe.folder)
        entries[entry["file"]] = entry
    return list(entries.values())


def build_release(out: Path, episodes: int = 2, gifs: Path | None = None,
                  recipe: RecipeSweep | None = None) -> list[dict]:
    """Record ``episodes`` episodes of the A* leader with each follower in each setting, and with ``recipe`` one
    replay per finished arm of the recipe ablation (the recipe replays already released stay); write index.json
    and return its entries."""
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    for setting, setting_text in SETTINGS.items():
        config = env_config(setting)
        for follower in FOLLOWERS:
            summary = policy_card(follower).summary
            leader_policy, follower_policy = make_policy("astar"), make_policy(follower)
            batch = run_episodes(config, leader_policy, follower_policy, episodes, RELEASE_SEED, record_hashes=True)
            folder = out / setting
            paths = record_batch(batch, "astar", follower, leader_policy, follower_policy, folder, "eval",
                                 meta={"setting": setting})
            for path in paths:
                entries.append(index_entry(load(path), path.relative_to(out).as_posix(), setting=setting,
                                           description=f"A* leader with the {follower} follower ({summary}); "
                                                       f"{setting_text}."))
            if gifs is not None and follower == "bayes" and setting in GIF_SETTINGS:
                from colorgrid.replay.export import export

                export(load(paths[0]), gifs / f"{setting}_astar+bayes.gif", "gif", cell=8)
    entries += recipe_entries(out, recipe)
    command = f"colorgrid replay release --out {out} --episodes {episodes}"
    write_index(out, entries, command + (f" --recipe {recipe.folder}" if recipe is not None else ""))
    return entries
