"""A baseline's per-seed figures, kept beside a sweep's results (``baselines.json``), for the claims that compare a
configuration with it (``b = { baseline = "astar/copy" }``, docs/SWEEPS.md).

The file is what ``colorgrid eval --leader LEADER --compare POLICY --episodes E --seed S`` gave on the evaluation
seeds of each trial seed (its ``command`` says which): ``seeds`` lists those evaluation seeds, and each baseline,
named ``<partner>/<policy>``, has ``<figure>_per_seed`` in the same order. A trial of seed ``s`` evaluates on
``evaluation_seed(s)``, so a seed's arm and the baseline played the same episodes: the claim pairs them by seed.
"""

from __future__ import annotations

import json
from pathlib import Path

from train.sweep.checks import SweepError

BASELINES_FILE = "baselines.json"
EVALUATION_SEED_OFFSET = 1_000_000
"""The trainer evaluates a run of seed ``s`` on seed ``1_000_000 + s`` (train/trainer.py, its evaluation)."""


def evaluation_seed(seed: int) -> int:
    """The evaluation seed of a trial of seed ``seed``."""
    return EVALUATION_SEED_OFFSET + int(seed)


def figure_name(metric: str) -> str:
    """The per-seed figure a claim's column reads from a baseline: the column without its evaluation stream and
    role (``eval_astar/follower_net_pickups``: ``net_pickups``), since a baseline is one follower's figures."""
    name = metric.rsplit("/", 1)[-1]
    for role in ("follower_", "leader_"):
        name = name.removeprefix(role)
    return name


def baseline_finals(results: Path | None, name: str, metric: str) -> dict[int, float]:
    """``{trial seed: figure}`` of the baseline ``name`` in the ``baselines.json`` of the ``results`` folder, for the
    claim column ``metric``: none while no such file is kept (the claim is then undecided: its side b has no
    figures); a kept file without the baseline or its figure is a one-line ``SweepError``."""
    path = None if results is None else Path(results) / BASELINES_FILE
    if path is None or not path.is_file():
        return {}
    kept = json.loads(path.read_text())
    baselines = kept.get("baselines", {})
    if name not in baselines:
        raise SweepError(f"baseline {name!r} is not in {path}: one of {sorted(baselines)}")
    figure = f"{figure_name(metric)}_per_seed"
    values = baselines[name].get(figure)
    if not isinstance(values, list) or len(values) != len(kept.get("seeds", [])):
        raise SweepError(f"baseline {name!r} in {path} has no {figure} for each of its seeds (the claim's column "
                         f"{metric!r})")
    return {int(s) - EVALUATION_SEED_OFFSET: float(v) for s, v in zip(kept["seeds"], values)}


FIGURES = ("net_pickups", "wrong_pickups", "goal_pickups", "block_reward")
"""The follower's figures kept per seed for each baseline (``<figure>_per_seed``), and their means."""


def declared_baselines(spec) -> list:
    """The baselines (``claim_spec.Baseline``) the claims of sweep ``spec`` compare with, then those its
    ``baselines`` list adds, each once, in file order."""
    from train.sweep.claim_spec import Baseline

    return list(dict.fromkeys([*(claim.b for claim in spec.claims if isinstance(claim.b, Baseline)), *spec.baselines]))


def partner_of(baseline, config) -> str:
    """The policy name of ``baseline``'s partner: the one of the trials' ``eval_partners`` whose evaluation stream it
    names (``population_people_held_out``: ``population:people#held_out``), or else a policy name itself (``ippo-leader``:
    a training partner, whose trials' main ``eval`` stream plays the same seeds); a one-line ``SweepError`` otherwise."""
    from colorgrid.policies.names import read_name
    from train.config import eval_stream

    streams = {eval_stream(partner).removeprefix("eval_"): partner for partner in config.eval_partners}
    if baseline.partner in streams:
        return streams[baseline.partner]
    if read_name(baseline.partner) is not None:
        return baseline.partner
    raise SweepError(f"baseline {baseline.name!r}: its partner {baseline.partner!r} is neither a policy name nor one "
                     f"of the trials' evaluation partners ({sorted(streams) or 'eval_partners is empty'})")


EVALUATION_FIELDS = ("env", "eval_episodes", "eval_partners")
"""What a trial's evaluation episodes are made of: one baseline figure a seed serves every configuration only
where these agree."""


def shared_evaluation(spec):
    """The training config of the file's first configuration, once every configuration is evaluated as it is (the
    same environment, episode count and evaluation partners, ``EVALUATION_FIELDS``): a baseline is evaluated once a
    seed for all of them; a one-line ``SweepError`` naming the first that differs otherwise."""
    seed = spec.all_seeds[0]
    first, *others = spec.configurations()
    config = spec.config(first, seed)
    for values in others:
        other = spec.config(values, seed)
        for field in EVALUATION_FIELDS:
            if getattr(other, field) != getattr(config, field):
                raise SweepError(f"{spec.path}: configuration {spec.label(values)} has another {field} than "
                                 f"{spec.label(first)}: its trials play other evaluation episodes, so one baseline a "
                                 "seed cannot pair with both (give each its own sweep file)")
    return config


def compute_baselines(spec, say=print) -> dict:
    """What ``colorgrid sweep baselines FILE`` keeps as ``baselines.json``: each baseline the file's claims name,
    its policy as the follower beside its partner, evaluated on each trial seed's evaluation seed with the trials'
    environment and episode count (``colorgrid.evaluate.evaluate``, as ``colorgrid eval --leader PARTNER --follower
    POLICY --episodes E --seed S``): the same episodes a trial of that seed is evaluated on."""
    from colorgrid.evaluate import evaluate

    baselines = declared_baselines(spec)
    if not baselines:
        raise SweepError(f"{spec.path}: no claim compares with a baseline (b = {{ baseline = '<partner>/<policy>' }}) "
                         "and it lists no baselines = ['<partner>/<policy>', ...]")
    config = shared_evaluation(spec)
    seeds = [evaluation_seed(s) for s in spec.all_seeds]
    kept = {}
    for baseline in baselines:
        partner = partner_of(baseline, config)
        per_seed = {figure: [] for figure in FIGURES}
        for seed in seeds:
            report = evaluate(config.env, partner, baseline.policy, config.eval_episodes, seed)
            follower = report["agents"]["follower"]
            for figure in FIGURES:
                per_seed[figure].append(float(follower[figure]["mean"]))
            say(f"{baseline.name}: seed {seed}: net pickups {per_seed['net_pickups'][-1]:+.2f}, "
                f"wrong pickups {per_seed['wrong_pickups'][-1]:.2f}")
        kept[baseline.name] = {**{f"{figure}_per_seed": values for figure, values in per_seed.items()},
                               **{figure: sum(values) / len(values) for figure, values in per_seed.items()}}
    return {"command": f"colorgrid sweep baselines {spec.path.name} ({config.eval_episodes} episodes a seed, env "
                       "seeded as each trial's evaluation: 1,000,000 + the trial's seed)",
            "seeds": seeds, "episodes": config.eval_episodes, "baselines": kept}


def baseline_differences(computed: dict, kept: dict) -> list[str]:
    """Where a kept ``baselines.json`` differs from what the command gives now: one line each (a figure of a
    baseline at a seed, a baseline or seed missing); empty when every kept figure is reproduced."""
    out = []
    if kept.get("seeds") != computed["seeds"]:
        out.append(f"seeds: kept {kept.get('seeds')}, computed {computed['seeds']}")
    for name, figures in computed["baselines"].items():
        old = kept.get("baselines", {}).get(name)
        if old is None:
            out.append(f"{name}: not kept")
            continue
        for key, values in figures.items():
            if key in old and old[key] != values:
                out.append(f"{name} {key}: kept {old[key]}, computed {values}")
    return out


def write_baselines(spec, check: bool = False, say=print) -> int:
    """``colorgrid sweep baselines FILE [--check]``: compute the file's baselines and write them to its results
    folder's ``baselines.json`` (0), or with ``check`` compare them with the kept file and say what differs (1 if
    anything does, 0 if every kept figure is reproduced)."""
    if spec.results is None:
        raise SweepError(f"{spec.path}: no results folder ('results = ...'): baselines are kept beside its results")
    path = Path(spec.results) / BASELINES_FILE
    if check and not path.is_file():
        raise SweepError(f"{path} does not exist: run colorgrid sweep baselines {spec.path} first")
    computed = compute_baselines(spec, say)
    if check:
        differences = baseline_differences(computed, json.loads(path.read_text()))
        for line in differences:
            say(line)
        say(f"{path}: " + (f"{len(differences)} difference(s)" if differences else "every kept figure reproduced"))
        return 1 if differences else 0
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(computed, indent=1) + "\n")
    say(f"wrote {path}; commit it with the file's results")
    return 0
