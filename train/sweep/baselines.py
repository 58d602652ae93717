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
