"""A pack of trials trained as one: K runs whose networks have the same shapes, acting and updating together.

At the paper's batch (16 envs) a trial leaves most of a machine idle: a rollout step's layers
are a few microseconds of arithmetic each and as long again in calls, and an H100 waits on
Python. JaxMARL and PureJaxRL train many seeds as one program (``jax.vmap(make_train(config))``);
a ``Pack`` does the same with PyTorch. Each trial is a ``Trainer`` as ever, with its own envs,
partners, optimizers, generators, schedules, logs, evaluations and checkpoints; the pack only
decides *how* their learners act and update, through one ``Placement`` over all of them:

- on a CPU (``mode="stacked"``): the learners of every trial whose networks stack
  (``train.stacked.can_stack``) act in one set of batched operations, each layer one batched
  product for all of them; every learner updates as it would alone, at one torch thread, the
  learners spread over the threads (at 512-row minibatches a learner's update is bound by its
  products' arithmetic, which batching over learners does not speed up on a CPU);
- on a GPU (``mode="vmap"``): learners with the same network (an LSTM or not) act and update as one
  program each (``train.packed_acting``, ``train.packed_update``: their weights stacked, each
  step and minibatch one ``torch.func.vmap`` of the network and the PPO loss, forward and
  backward), each with its own minibatch order, loss weights, learning rate, gradient clip and
  early stop on KL (a learner that stops is masked, the others go on); a learner with a network
  of a shape no other has acts and updates on its own, as it would alone.

A trial computes what it computes alone, up to float rounding (``tests/test_pack.py``). A pack of
one trial is today's trainer: ``Trainer.train`` is ``Pack([trainer]).train``, and with one trial
the pack's placement is the trial's own (its learners act stacked, or side by side, and update in
processes or threads as ``train.placement`` says), bit for bit the same as before packs.

Trials may differ in any value that leaves their shapes alone (seed, kappa, annealing, learning
rate, reward weights, target KL, partner, total steps); ``pack_key`` says which settings must
agree (``train.packing``). A trial that finishes leaves the pack; the others go on.
"""

from __future__ import annotations

import time
from contextlib import ExitStack, suppress
from pathlib import Path
from typing import Callable

from typing import Generator, Protocol

import torch

from train.config import TrainConfig
from train.learner import Learner
from train.metrics import MetricsLog
from train.packing import check_packable
from train.placement import PACK_MODES, Placement


class Trainer(Protocol):
    """What a pack trains: a ``train.trainer.Trainer`` (named here by what the pack asks of it, so that the trainer
    may run itself as a pack of one without an import circle)."""

    config: TrainConfig
    learners: dict[int, Learner]
    placement: Placement
    run_dir: Path
    device: torch.device
    progress: bool
    step: int
    log: MetricsLog | None

    @property
    def finished(self) -> bool: ...
    def start(self) -> None: ...
    def begin_iteration(self) -> None: ...
    def rollout(self) -> Generator[Callable[[Learner], dict], dict, tuple[dict, dict]]: ...
    def collect_rollout(self) -> tuple[dict, dict]: ...
    def update_inputs(self) -> dict[int, dict]: ...
    def end_iteration(self, episodes: dict, accuracy: dict, results: dict[int, dict], t0: float, t1: float,
                      t2: float) -> dict: ...
    def after_iteration(self, row: dict, stopping: bool) -> Path | None: ...
    def close(self) -> None: ...


class Pack:
    """``trainers`` trained as one (see the module docstring); each keeps its own run folder."""

    def __init__(self, trainers: list[Trainer], mode: str = "auto"):
        """``mode``: how the learners of a pack of two or more act and update (``train.placement.PACK_MODES``)."""
        if not trainers:
            raise ValueError("a pack needs at least one trial")
        if mode not in PACK_MODES:
            raise ValueError(f"pack mode {mode!r}: one of {', '.join(PACK_MODES)}")
        check_packable([t.config for t in trainers])
        self.trainers, self.mode = trainers, mode
        self._placement: Placement | None = None
        self._members: tuple[int, ...] = ()  # the trials the placement serves

    # ------------------------------------------------------------------ placement
    def placement(self, members: tuple[int, ...]) -> Placement:
        """Where the learners of trials ``members`` act and update: a lone trial's own placement, else one placement
        over all their learners (keyed ``(trial, learner key)``), packed."""
        if len(members) == 1:
            return self.trainers[members[0]].placement
        if members != self._members:
            if self._placement is not None:
                self._placement.close()
            for k in members:  # (a trial's own threads and processes end, its optimizers' states brought back)
                self.trainers[k].placement.close()
            first = self.trainers[members[0]]
            learners = {(k, i): lr for k in members for i, lr in self.trainers[k].learners.items()}
            self._placement, self._members = Placement(learners, first.device, False, packed=True,
                                                     pack_mode=self.mode), members
        return self._placement

    # ------------------------------------------------------------------ loop
    def train(self, on_iteration: Callable[[dict[int, tuple[dict, Path | None]]], None] | None = None,
              stop: Callable[[], bool] | None = None) -> list[dict]:
        """Train every trial to its ``total_steps``; ``on_iteration(done)`` after each iteration of the pack, with
        each trial that took part (by its index in the pack) mapped to its log row and the checkpoint it saved, or
        None. ``stop()``, asked after each iteration: true ends every trial there, each with a checkpoint. Returns
        each trial's last row."""
        last: list[dict] = [{} for _ in self.trainers]
        ended = False
        with ExitStack() as logs:
            for trainer in self.trainers:
                trainer.start()
                logs.callback(trainer.log.close)
            bar = self._progress_bar()
            if bar is not None:
                logs.callback(bar.close)
            try:
                while not all(t.finished for t in self.trainers):
                    members = tuple(k for k, t in enumerate(self.trainers) if not t.finished)
                    rows = self.train_iteration(members)
                    stopping = stop is not None and stop()
                    done = {k: (row, self.trainers[k].after_iteration(row, stopping)) for k, row in zip(members, rows)}
                    for k, row in zip(members, rows):
                        last[k] = row
                    if on_iteration is not None:
                        on_iteration(done)
                    if bar is not None:
                        bar.update(sum(self.trainers[k].config.batch_steps for k in members))
                        if len(self.trainers) == 1:
                            bar.set_postfix(sps=f"{rows[0]['sps']:.0f}",
                                            team=f"{rows[0].get('team_reward', float('nan')):.2f}")
                    if stopping:
                        break
                ended = True
            finally:
                if ended:
                    self.close()
                else:  # (an error or Ctrl+C is on its way out: nothing here may hide it)
                    with suppress(Exception):
                        self.close()
        return last

    def _progress_bar(self):
        """One bar over every trial's env steps, when the first trial asks for progress."""
        if not self.trainers[0].progress:
            return None
        from tqdm import tqdm

        return tqdm(total=sum(t.config.end_step for t in self.trainers), initial=sum(t.step for t in self.trainers),
                    unit="step", smoothing=0.1)

    def train_iteration(self, members: tuple[int, ...] | None = None) -> list[dict]:
        """One PPO iteration of each trial in ``members`` (default: all), rolled out and updated together; returns
        each one's log row, in order. Each row's speeds are the pack's: its own steps over the pack's time."""
        members = tuple(range(len(self.trainers))) if members is None else members
        trainers = [self.trainers[k] for k in members]
        placement = self.placement(members)
        for trainer in trainers:
            trainer.begin_iteration()
        t0 = time.perf_counter()
        outcomes = self._collect_rollouts(members, placement)
        t1 = time.perf_counter()
        inputs = {(k, i): x for k in members for i, x in self.trainers[k].update_inputs().items()}
        results = placement.update(inputs if len(members) > 1 else {i: x for (_, i), x in inputs.items()})
        t2 = time.perf_counter()
        rows = []
        for k, trainer, (episodes, accuracy) in zip(members, trainers, outcomes):
            own = ({i: r for (m, i), r in results.items() if m == k} if len(members) > 1 else results)
            rows.append(trainer.end_iteration(episodes, accuracy, own, t0, t1, t2))
        return rows

    def _collect_rollouts(self, members: tuple[int, ...], placement: Placement) -> list[tuple[dict, dict]]:
        """Every member's rollout (``Trainer.rollout``), step by step together, the learners acting through
        ``placement``; returns each one's episode means and goal accuracies."""
        if len(members) == 1:
            return [self.trainers[members[0]].collect_rollout()]
        rollouts = [self.trainers[k].rollout() for k in members]
        owner = {id(lr): n for n, k in enumerate(members) for lr in self.trainers[k].learners.values()}
        outcomes: list = [None] * len(members)
        with placement.acting() as act:
            asks = [next(r) for r in rollouts]
            while any(outcome is None for outcome in outcomes):
                acted = act(lambda lr: asks[owner[id(lr)]](lr))
                for n, (k, rollout) in enumerate(zip(members, rollouts)):
                    try:
                        asks[n] = rollout.send({i: acted[(k, i)] for i in self.trainers[k].learners})
                    except StopIteration as done:
                        outcomes[n] = done.value
                    except Exception as error:
                        error.add_note(f"in the pack's trial {k} ({self.trainers[k].run_dir})")
                        raise
        return outcomes

    def close(self) -> None:
        """End the threads and processes every trial's learners update on."""
        if self._placement is not None:
            self._placement.close()
            self._placement, self._members = None, ()
        for trainer in self.trainers:
            trainer.close()
