"""Run a sweep's trials as plain processes on this machine, without Ray: ``colorgrid sweep run FILE --local N``.

For a machine that has no Ray (a lent GPU machine, a laptop) or a sweep spread over machines by hand. The
sweep's folder looks as a Ray sweep's does to everything that reads it (``collect``, ``publish``, ``report``):
a folder per trial holding ``params.json`` and the training run (``run/``). A trial's folder is named from its
configuration and seed (``trial_local_<hash>``), so the same command again finds it: a finished trial is
skipped, a trial with a checkpoint continues from it (exactly as if never stopped: the trainer's checkpoints
hold every random state), and a trial kept in the sweep file's ``results`` folder is not run. ``stop_after``
seconds end every trial with a checkpoint of its last iteration; so do Ctrl+C and SIGTERM.

A folder is run by one executor: a Ray sweep's folder refuses ``--local`` and a local sweep's refuses
``sweep run`` without it (their trial folders would both hold the same trials).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
import zlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

from train.sweep.checks import SweepError
from train.sweep.declared import declare
from train.sweep.spec import SPEC_FILE, WORKDIR_FILE, SweepSpec, grid, load_folder
from train.sweep.trial import RUN_FOLDER

LOCAL_FILE = "local"
"""A file in a sweep's folder saying its trials run as plain processes (``--local``)."""
RAY_STATE = "tuner.pkl"
"""What Ray Tune leaves in a sweep's folder."""
EVERY_S = 30.0
"""Seconds between a running trial's progress lines."""


def local_name(spec: SweepSpec, params: dict) -> str:
    """A trial's folder: the same for the same configuration and seed, whatever else the file holds."""
    key = f"{spec.label(spec.values(params))}|{int(params['seed'])}"
    return f"trial_local_{zlib.crc32(key.encode()):08x}"


def run_local(spec: SweepSpec, processes: int, stop_after: float | None = None) -> int:
    """Run (or continue) every trial of ``spec`` in ``spec.out`` with ``processes`` at a time, then write the
    folder's tables; returns the exit status (0: every trial finished; 130: stopped before that, continue with the
    same command)."""
    from train.sweep.results import collect, committed_keys, finished, results_folder

    if processes < 1:
        raise SweepError(f"--local takes the number of trials to run at a time (>= 1), got {processes}")
    if stop_after is not None and stop_after <= 0:
        raise SweepError(f"--stop-after takes seconds (> 0), got {stop_after}")
    folder = spec.out.resolve()
    if (folder / RAY_STATE).exists():
        raise SweepError(f"{folder} holds a sweep run on Ray Tune; finish it with colorgrid sweep resume {spec.out}, "
                         f"or choose another --out for --local")
    if (folder / SPEC_FILE).exists() and not same_sweep(spec, folder):
        raise SweepError(f"{folder} holds a sweep of another file (its {SPEC_FILE} trains other trials); choose "
                         f"another --out")
    spec.check_files()
    folder.mkdir(parents=True, exist_ok=True)
    (folder / SPEC_FILE).write_text(spec.text)
    (folder / WORKDIR_FILE).write_text(os.getcwd())
    (folder / LOCAL_FILE).write_text("trials run as plain processes: colorgrid sweep run FILE --local N\n")
    declare(spec, folder)  # each claim's digest, before the first trial starts (train/sweep/declared.py)
    kept = committed_keys(spec, folder)
    todo, skipped = [], 0
    for params in grid(spec):
        if spec.key(params) in kept:
            skipped += 1
        elif not finished(spec, folder / local_name(spec, params), params):
            todo.append(params)
    where = results_folder(spec, folder)
    print(f"sweep {spec.name}: {spec.summary()} into {folder}, {processes} at a time without Ray"
          + (f"; {skipped} kept in {where}" if skipped else "")
          + f"; {spec.num_trials() - skipped - len(todo)} finished here before; {len(todo)} to run", flush=True)
    deadline = None if stop_after is None else time.time() + stop_after
    failed = []
    context = get_context("spawn")
    stop = context.Event()
    jobs = trial_packs(spec, todo)
    if spec.resources.pack > 1 and todo:
        print(f"sweep {spec.name}: {len(todo)} trials in {len(jobs)} packs of up to {spec.resources.pack}, "
              f"{processes} at a time", flush=True)
    with ProcessPoolExecutor(max_workers=processes, mp_context=context, initializer=share_stop,
                             initargs=(stop,)) as pool:
        futures = {pool.submit(run_pack, str(folder), job, deadline, waited=i >= processes): job
                   for i, job in enumerate(jobs)}

        def stop_all(*_) -> None:  # running trials end with a checkpoint, waiting ones do not start
            stop.set()
            for future in futures:
                future.cancel()

        previous = {sig: signal.signal(sig, stop_all) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            for future in as_completed(futures):
                if future.cancelled():
                    continue
                error = future.exception()
                if error is not None:
                    failed.append(", ".join(f"[{spec.label(spec.values(p))}, seed={p['seed']}]"
                                            for p in futures[future])
                                  + f": {str(error).splitlines()[0] if str(error) else type(error).__name__}")
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    collect(folder)
    done = sum(finished(spec, folder / local_name(spec, p), p) for p in todo)
    print(f"sweep {spec.name}: {done} of {len(todo)} trials ran to the end here"
          + (f", {len(failed)} failed" if failed else "") + f"; tables in {folder}", flush=True)
    if failed:
        print(f"first failure: {failed[0]} (the same command again continues a failed trial from its last "
              f"checkpoint)", file=sys.stderr)
        return 1
    if done < len(todo):
        print("stopped before its end; continue it with the same command", flush=True)
        return 130
    return 0


def same_sweep(spec: SweepSpec, folder: Path) -> bool:
    """Whether the sweep in ``folder`` trains its trials as ``spec`` does (a file that adds seeds, claims or words
    to it continues it)."""
    text = (folder / SPEC_FILE).read_text()
    if text == spec.text:
        return True
    try:
        return load_folder(folder).same_trials(spec)
    except SweepError:
        return False


_STOP = None
"""The sweep's stop event in a trial's process (set by the parent on Ctrl+C or SIGTERM)."""


def share_stop(event) -> None:
    global _STOP
    _STOP = event
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent asks every trial to stop through the event


def trial_packs(spec: SweepSpec, todo: list[dict]) -> list[list[dict]]:
    """The trials to run, in packs of up to ``[resources] pack`` trials whose shapes agree (``train.packing``); one
    trial a pack without it."""
    from train.packing import pack_key, packs
    from train.sweep.trial import trial_config

    return packs(todo, lambda params: pack_key(trial_config(spec, params)), spec.resources.pack)


def run_pack(folder: str, pack: list[dict], deadline: float | None, waited: bool = False) -> None:
    """The trials ``pack`` (parameter values of each) as one pack in this process (``train.pack``; one trial: an
    ordinary run): each trains from its checkpoint if it has one, and all stop with a checkpoint at ``deadline`` or
    on SIGINT / SIGTERM. A pack that ``waited`` for its turn does not start once the sweep is stopping."""
    if waited and ((_STOP is not None and _STOP.is_set()) or (deadline is not None and time.time() >= deadline)):
        return
    from train.pack import Pack
    from train.sweep.trial import trial_trainer

    asked = []
    signal.signal(signal.SIGTERM, lambda *_: asked.append(True))
    spec = load_folder(Path(folder))
    workdir = Path(folder) / WORKDIR_FILE
    os.chdir(workdir.read_text().strip())  # paths in the sweep file read as where it was started
    trainers = [trial_trainer(spec, params, Path(folder) / local_name(spec, params)) for params in pack]
    labels = [f"trial [{spec.label(spec.values(params))}, seed={params['seed']}]" for params in pack]
    last_line = [0.0] * len(pack)

    def report(done: dict[int, tuple[dict, Path | None]]) -> None:
        for k, (row, _) in done.items():
            now, trainer = time.time(), trainers[k]
            if now - last_line[k] >= EVERY_S or trainer.finished:
                last_line[k] = now
                value = row.get(spec.metric)
                shown = f" {spec.metric} {value:+.2f}" if isinstance(value, (int, float)) else ""
                print(f"{labels[k]} step {trainer.step:,}/{trainer.config.end_step:,}{shown}, "
                      f"{row.get('sps', 0):,.0f} steps/s", flush=True)

    Pack(trainers).train(on_iteration=report, stop=lambda: bool(asked) or (_STOP is not None and _STOP.is_set())
                         or (deadline is not None and time.time() >= deadline))
