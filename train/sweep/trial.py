"""One trial of a sweep: an ordinary training run, reported to Ray Tune.

The trial builds its ``TrainConfig`` from the sweep file and its parameter values, restores the
run from Tune's checkpoint when Tune restarts it (after a crash, a lost node or ``sweep
resume``), calls ``Trainer.train`` and reports every iteration's log row, and each checkpoint the
trainer saves, to Tune. A resumed run continues exactly as if never stopped (the trainer's
checkpoints hold every random state), so a restarted trial ends with the metrics it would have had.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from train.sweep.spec import SweepSpec

PACK = "pack"
"""The key of a Tune trial's parameters that lists the sweep's trials it trains as one pack."""
RUN_FOLDER = "run"
"""The training run's folder inside the trial's folder (config.json, metrics.jsonl, train.csv, ...)."""


def trial_folder(trial_id: str) -> str:
    """The name of a trial's folder in the sweep's folder."""
    return f"trial_{trial_id}"


def trial_config(spec: SweepSpec, params: dict):
    """The trial's training config: the sweep's, with its parameter values, seed, thread count and device."""
    import dataclasses

    config = spec.config(spec.values(params), int(params["seed"]))
    threads = max(1, math.ceil(spec.resources.cpus_per_trial))
    device = "cuda" if spec.resources.gpus_per_trial > 0 else "cpu"
    # learners update on threads, never in forked processes: a Ray worker runs gRPC's threads, which are not
    # safe to fork (the same results bit for bit; docs/TRAINING.md)
    return dataclasses.replace(config, threads=threads, device=device, update_processes=False)


def run_trial(params: dict, spec: SweepSpec, workdir: str, kept: frozenset = frozenset()) -> None:
    """Tune's function trainable: train one configuration and seed, reporting as it goes; a trial whose
    (configuration, seed) is in ``kept`` (its results kept in the sweep's results folder) ends at once."""
    import ray
    from ray import tune

    if Path(workdir).is_dir():  # paths in the sweep file (checkpoints, populations) read as where it was started
        os.chdir(workdir)
    if PACK in params:
        return run_pack_trial(params[PACK], spec, kept)
    config = trial_config(spec, params)
    if not spec.wants(params):  # Tune's grid crosses every seed with every configuration; [[more_seeds]] does not
        tune.report({spec.metric: math.nan, "step": 0, "total_steps": 0, "skipped": 1.0})
        return
    if spec.key(params) in kept:
        total = config.end_step
        tune.report({spec.metric: math.nan, "step": total, "total_steps": total, "kept": 1.0})
        return
    limit_threads(config.threads)
    from train.trainer import Trainer

    # in the sweep's folder, not Tune's get_trial_dir(): that is a local staging folder, and a reused worker's
    # is never copied to the sweep's folder
    run_dir = Path(spec.out) / trial_folder(tune.get_context().get_trial_id()) / RUN_FOLDER
    trainer = Trainer(config, run_dir, progress=False, keep_steps=False)
    checkpoint = tune.get_checkpoint()
    if checkpoint is not None:
        with checkpoint.as_directory() as folder:
            trainer.restore(Path(folder) / "latest.pt")
    node = ray.get_runtime_context().get_node_id()
    threads = thread_counts()

    def report(row: dict, saved: Path | None) -> None:
        metrics = {k: float(v) for k, v in row.items() if isinstance(v, (int, float))}
        metrics.setdefault(spec.metric, math.nan)  # Tune needs the metric in every report; NaN: none this time
        metrics.update(step=trainer.step, total_steps=config.end_step, node_id=node,
                       **threads)
        if saved is None:
            tune.report(metrics)
        else:
            tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(str(saved.parent)))

    trainer.train(on_iteration=report)


def run_pack_trial(pack: list[dict], spec: SweepSpec, kept: frozenset = frozenset()) -> None:
    """A Tune trial that trains a pack of the sweep's trials as one (``[resources] pack``; ``train.pack``). Each
    trial of the pack has a folder of its own beside the Tune trial's (``trial_ID_k``: its ``params.json``, run and
    a ``result.json`` of the node and thread counts, as an unpacked trial's), so that the tables, reports and kept
    results read it as any trial; Tune sees the
    pack: each report holds the mean of the trials' metric, and its checkpoint every trial's ``latest.pt``
    (``k/latest.pt``), from which a restarted pack continues each trial exactly. A trial kept in the sweep's
    results folder since the pack was made is not trained."""
    import shutil
    import tempfile

    from ray import tune

    import ray

    from train.pack import Pack

    base = Path(spec.out) / trial_folder(tune.get_context().get_trial_id())
    trainers = {k: trial_trainer(spec, params, Path(f"{base}_{k}"), restore=False) for k, params in enumerate(pack)
                if spec.key(params) not in kept}
    if not trainers:
        tune.report({spec.metric: math.nan, "step": 0, "total_steps": 0, "kept": 1.0})
        return
    checkpoint = tune.get_checkpoint()
    if checkpoint is not None:
        with checkpoint.as_directory() as saved:
            for k, trainer in trainers.items():
                if (Path(saved) / str(k) / "latest.pt").exists():  # (one that had saved none starts afresh)
                    trainer.restore(Path(saved) / str(k) / "latest.pt")
    order = list(trainers)  # the pack's trial index -> the pack member's
    threads = thread_counts()

    node = ray.get_runtime_context().get_node_id()

    def report(done: dict[int, tuple[dict, Path | None]]) -> None:
        for k in done:  # what only Tune's reports hold of an unpacked trial, in each trial's own result.json
            with open(trainers[k].run_dir.parent / "result.json", "a") as log:
                log.write(json.dumps({"step": trainers[k].step, "node_id": node, **threads}) + "\n")
        values = [row.get(spec.metric, math.nan) for row, _ in done.values()]
        metrics = {spec.metric: float(np.nanmean(values)) if not np.isnan(values).all() else math.nan,
                   "step": min(t.step for t in trainers.values()),
                   "total_steps": max(t.config.end_step for t in trainers.values()), "pack": len(trainers), **threads}
        if not any(saved for _, saved in done.values()):
            tune.report(metrics)
            return
        with tempfile.TemporaryDirectory() as folder:  # every trial's latest checkpoint, saved now or before
            for k, trainer in trainers.items():
                latest = trainer.run_dir / "checkpoints" / "latest.pt"
                if latest.exists():
                    (Path(folder) / str(k)).mkdir()
                    shutil.copy2(latest, Path(folder) / str(k) / "latest.pt")
            tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(folder))

    Pack([trainers[k] for k in order]).train(on_iteration=lambda done: report({order[i]: v for i, v in done.items()}))


def trial_trainer(spec: SweepSpec, params: dict, folder: Path, restore: bool = True):
    """The ``Trainer`` of the sweep's trial ``params`` in ``folder`` (made, with its ``params.json``; the trial's
    threads set), continued from its checkpoint there when ``restore`` and it has one."""
    from train.trainer import Trainer

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "params.json").write_text(json.dumps(params))
    config = trial_config(spec, params)
    limit_threads(config.threads)
    trainer = Trainer(config, folder / RUN_FOLDER, progress=False, tensorboard=False, keep_steps=False)
    latest = folder / RUN_FOLDER / "checkpoints" / "latest.pt"
    if restore and latest.exists():
        trainer.restore(latest)
    return trainer


def limit_threads(threads: int) -> None:
    """Torch and numba use at most ``threads`` threads (the trial's CPU allotment)."""
    import numba
    import torch

    torch.set_num_threads(threads)
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))


def thread_counts() -> dict[str, int]:
    """The threads torch and numba compute with in this process (reported with every iteration)."""
    import numba
    import torch

    return {"torch_threads": torch.get_num_threads(), "numba_threads": numba.get_num_threads()}
