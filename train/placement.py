"""Where the learners run: one after the other, side by side on threads, their updates in processes of their own, or
their acting through one stacked batch. The trainer says *what* runs; a ``Placement`` decides *where*.

A ``Placement`` serves one trainer's learners for the whole run (or a pack's: below):

- ``acting()``: for one rollout, a function that makes every learner act on its inputs
  (``act(inputs_of) -> {key: (actions, goal_probs)}``), on threads (``side_by_side``), or through
  ``train.stacked.StackedActing`` where the networks allow it (``can_stack``);
- ``update(inputs)``: every learner's PPO update on the rollout just collected, on threads, or with
  all but the first in a ``train.update_process.UpdateProcess`` each;
- ``sync_optimizers()``: each learner's optimizer state brought back from the process it updates in
  (for a checkpoint); ``close()``: the threads and processes ended (the next update starts them again).

Every placement of one trainer gives the same results bit for bit: the learners share nothing (own model, optimizer,
buffers, random generator), and each one's work runs at one torch thread count whatever runs beside it
(``tests/test_train.py`` checks; docs/TRAINING.md).

A pack of trials (``train.pack``) has one ``packed`` placement over all its trials' learners, keyed
``(trial, learner key)``: each group of learners whose networks stack acts as one ``StackedActing``, and
the learners update each at one thread spread over the threads (a CPU) or, grouped by network, as one
batched program (``train.packed_update``; a GPU). On a CPU a trial in a pack computes what it computes
alone, bit for bit, when its learners act stacked and update at one thread alone too; with ``vmap``, to
float rounding (``tests/test_pack.py``; docs/TRAINING.md).
"""

from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Callable, Hashable, Iterator, TypeVar

import numpy as np
import torch

from train.learner import Learner
from train.packed_acting import PackedActing
from train.packed_update import PackedUpdate, can_pack_update
from train.stacked import StackedActing, can_stack
from train.update_process import AVAILABLE as UPDATE_PROCESSES, Unavailable, UpdateProcess

R = TypeVar("R")
PACK_MODES = {"auto": "stacked on a CPU, vmap on any other device",
              "stacked": "acting through train.stacked where the networks stack, every learner's own update at one "
                         "thread, the learners spread over the torch threads",
              "vmap": "acting and updating as one torch.func.vmap program per network shape (train.packed_acting, "
                      "train.packed_update)"}
"""How a pack's learners act and update (``Placement(pack_mode=...)``, ``Pack(mode=...)``)."""
Acted = dict[Hashable, tuple[np.ndarray, np.ndarray]]
"""Each learner's sampled actions ``[rows]`` and goal probabilities ``[rows, C]``, by learner key."""


def pick_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("device='cuda' but no CUDA device is available; use 'auto' or 'cpu'")
    return torch.device(name)


def device_name(device: torch.device) -> str:
    """What trained: the GPU's name, or the CPU's with its thread count."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    from colorgrid.machine import cpu_name

    return f"{cpu_name()} ({torch.get_num_threads()} torch threads)"


def side_by_side(learners: dict[int, Learner], work: Callable[[Learner], R],
                 pool: ThreadPoolExecutor | None) -> dict[int, R]:
    """``work(learner)`` for every learner, by key: the first on the calling thread and the others on ``pool``'s,
    all at the calling thread's torch thread count (set on each worker itself: OpenMP keeps the count per thread);
    one after the other without a pool. The learners share nothing (own model, optimizer, buffers, random
    generator), so the results are those of the learners one after the other, whatever the threads' timing."""
    if pool is None:
        return {i: work(lr) for i, lr in learners.items()}
    threads = torch.get_num_threads()
    (first, learner), *others = learners.items()
    futures = {i: pool.submit(at_threads, threads, work, lr) for i, lr in others}
    return {first: work(learner), **{i: f.result() for i, f in futures.items()}}


def at_threads(threads: int, work: Callable, *args):
    """``work(*args)`` at ``threads`` torch threads, set on the calling thread."""
    torch.set_num_threads(threads)
    return work(*args)


class Placement:
    """Where ``learners`` (by key) act and update: see the module docstring. ``update_processes``: a learner may
    update in a process of its own (``TrainConfig.update_processes``)."""

    def __init__(self, learners: dict[Hashable, Learner], device: torch.device, update_processes: bool,
                 packed: bool = False, pack_mode: str = "auto"):
        if pack_mode not in PACK_MODES:
            raise ValueError(f"pack mode {pack_mode!r}: one of {', '.join(PACK_MODES)}")
        self.learners, self.device, self.update_processes = learners, device, update_processes
        self.packed = packed  # a pack's learners (``train.pack``): acting and updating by groups of one shape
        self.pack_mode = ("stacked" if device.type == "cpu" else "vmap") if pack_mode == "auto" else pack_mode
        self._stacked_groups: list | None = None  # packed: (learner keys, how they act as one or None), made once
        self._update_groups: list | None = None  # packed: (learner keys, their PackedUpdate or None), made once
        self._pool: ThreadPoolExecutor | None = None  # the update's threads, kept between updates
        self._processes: dict[int, UpdateProcess] = {}  # by learner key: where that learner updates
        self._processes_work = UPDATE_PROCESSES  # false once one could not start here (``Unavailable``)
        self._stacked: StackedActing | None = None

    # -------------------------------------------------------------- acting
    @contextmanager
    def acting(self) -> Iterator[Callable[[Callable[[Learner], dict]], Acted]]:
        """For one rollout: ``act(inputs_of)``, every learner's step on its inputs ``inputs_of(learner)``.

        Stacked where the networks allow it (at one torch thread: its operations are small), else
        on the threads of ``threads_each``, with this thread at the per-learner torch thread count
        while inside (the rollout's other torch ops too: they are far too small to gain from more).
        """
        if self.packed:
            with self._acting_packed() as act:
                yield act
            return
        threads, stacked = torch.get_num_threads(), self._stacked_acting()
        if stacked is not None:
            torch.set_num_threads(1)
            try:
                stacked.refresh()  # this update's weights
                yield lambda inputs_of: dict(zip(self.learners, stacked.act([inputs_of(lr)
                                                                             for lr in self.learners.values()])))
            finally:
                torch.set_num_threads(threads)
            return
        each = self.threads_each()
        if each is None:
            yield lambda inputs_of: side_by_side(self.learners, lambda lr: lr.act(inputs_of(lr)), None)
            return
        torch.set_num_threads(each)
        try:
            with ThreadPoolExecutor(min(len(self.learners), threads) - 1, thread_name_prefix="actor") as pool:
                yield lambda inputs_of: side_by_side(self.learners, lambda lr: lr.act(inputs_of(lr)), pool)
        finally:
            torch.set_num_threads(threads)

    def _stacked_acting(self) -> StackedActing | None:
        """The learners' acting in one set of batched operations (``refresh`` it to their current weights), where
        their networks allow it (``train.stacked.can_stack``: the fast feed-forward network on the CPU), else None."""
        if self._stacked is None and can_stack(list(self.learners.values())):
            self._stacked = StackedActing(list(self.learners.values()))
        return self._stacked

    def threads_each(self) -> int | None:
        """Torch threads per learner when the learners act and update side by side, else None.

        On a CPU with two or more learners and two or more torch threads, they run on
        ``min(learners, threads)`` threads with ``max(1, threads // learners)`` torch threads
        each: small networks use one core each far better than two cores one after the other,
        and torch ops and the compiled view kernels release the GIL.
        """
        threads = torch.get_num_threads()
        if self.device.type != "cpu" or len(self.learners) < 2 or threads < 2:
            return None
        return max(1, threads // len(self.learners))

    # -------------------------------------------------------------- update
    def update(self, inputs: dict[Hashable, dict]) -> dict[Hashable, dict]:
        """Every learner's PPO update on the rollout just collected, bootstrapped from the values of ``inputs``
        (its network inputs now, by learner key), side by side where it can (``threads_each``); packed, as
        ``_update_packed`` says.

        Each one's whole update, its bootstrap value included, runs at one thread count, so the
        result is bit for bit the learners updated one after the other with that many threads,
        on any CPU. (It is not bit for bit an update with all the threads: on some CPUs MKL and
        oneDNN split a small matrix product's sum across threads; see docs/TRAINING.md.)
        """
        if self.packed:
            return self._update_packed(inputs)
        key_of = {id(lr): key for key, lr in self.learners.items()}
        work = lambda lr: lr.update(lr.value(inputs[key_of[id(lr)]]))  # noqa: E731
        each, threads = self.threads_each(), torch.get_num_threads()
        if each == 1 and len(self.learners) <= threads and self.update_processes and self._processes_work:
            try:
                return self._update_in_processes(inputs)
            except Unavailable as error:
                self._processes_work = False
                warnings.warn(f"{error}: the learners update on threads instead (update_processes)", stacklevel=3)
        self._close_processes()  # (a learner that updated in its process: its optimizer state comes back first)
        if each is None:
            return side_by_side(self.learners, work, None)
        if self._pool is None:
            self._pool = ThreadPoolExecutor(min(len(self.learners), threads) - 1, thread_name_prefix="learner")
        torch.set_num_threads(each)
        try:
            return side_by_side(self.learners, work, self._pool)
        finally:
            torch.set_num_threads(threads)

    def _update_in_processes(self, inputs: dict[Hashable, dict]) -> dict[Hashable, dict]:
        """``update`` with the first learner on this thread and each other in its process (``UpdateProcess``),
        all at one torch thread."""
        first, *others = self.learners
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        failed = True
        try:
            for i in others:
                if i not in self._processes:
                    self._processes[i] = UpdateProcess(self.learners[i])
            for i in others:
                learner = self.learners[i]
                self._processes[i].start(learner, learner.value(inputs[i]))
            learner = self.learners[first]
            results = {first: learner.update(learner.value(inputs[first]))}
            results.update({i: self._processes[i].finish(self.learners[i]) for i in others})
            failed = False
            return results
        finally:
            torch.set_num_threads(threads)
            if failed:  # (the learners' states are those of an update cut short: end the processes now)
                self._close_processes(keep_state=False)

    # -------------------------------------------------------------- packed
    def _packed_groups(self, fits: Callable[[list[Learner]], bool], make: Callable[[list[Learner]], object]
                       ) -> list[tuple[list[Hashable], object | None]]:
        """The learners in groups that ``fits`` (each grouped with every later learner it fits with), each made into
        ``make(group)``; a learner that fits with none is a group of its own, with None."""
        groups, left = [], list(self.learners)
        while left:
            first, *rest = left
            group = [first] + [k for k in rest if fits([self.learners[first], self.learners[k]])]
            learners = [self.learners[k] for k in group]
            if len(group) > 1 and fits(learners):
                groups.append((group, make(learners)))
            else:
                group = [first]
                groups.append((group, None))
            left = [k for k in left if k not in group]
        return groups

    @contextmanager
    def _acting_packed(self) -> Iterator[Callable[[Callable[[Learner], dict]], Acted]]:
        """A pack's acting: each group of learners that stack (``can_stack``) in one ``StackedActing``, the others
        one by one, all at one torch thread (a rollout step's operations are small), or with ``pack_mode="vmap"``
        each group of one network shape in one ``PackedActing``, at the thread count as it is."""
        if self._stacked_groups is None:
            self._stacked_groups = (self._packed_groups(can_stack, StackedActing) if self.pack_mode == "stacked" else
                                    self._packed_groups(can_pack_update, PackedActing))
        threads = torch.get_num_threads()
        torch.set_num_threads(1 if self.pack_mode == "stacked" else threads)
        try:
            for _, stacked in self._stacked_groups:
                if stacked is not None:
                    stacked.refresh()

            def act(inputs_of: Callable[[Learner], dict]) -> Acted:
                out = {}
                for keys, stacked in self._stacked_groups:
                    if stacked is None:
                        out[keys[0]] = self.learners[keys[0]].act(inputs_of(self.learners[keys[0]]))
                    else:
                        out.update(zip(keys, stacked.act([inputs_of(self.learners[k]) for k in keys])))
                return out

            yield act
        finally:
            torch.set_num_threads(threads)

    def _update_packed(self, inputs: dict[Hashable, dict]) -> dict[Hashable, dict]:
        """A pack's update. With ``pack_mode="vmap"`` (what a GPU gets), each group of learners with the same
        network (``can_pack_update``, an LSTM or not) as one program (``PackedUpdate``), the others one by one, with
        every torch thread. With ``"stacked"`` (a CPU's), every learner's own update at one torch thread,
        the learners spread evenly over ``threads`` threads: at a minibatch of 512 rows a learner's update is bound
        by its products' arithmetic, which a batched product does no faster (docs/PERFORMANCE.md), and each
        learner's update at one thread is what it is in a trial alone on a CPU, bit for bit."""
        if self.pack_mode == "stacked":
            return self._update_each(inputs)
        if self._update_groups is None:
            self._update_groups = self._packed_groups(can_pack_update, PackedUpdate)
        out = {}
        for keys, packed in self._update_groups:
            if packed is None:
                learner = self.learners[keys[0]]
                out[keys[0]] = learner.update(learner.value(inputs[keys[0]]))
            else:
                out.update(zip(keys, packed.update([inputs[k] for k in keys])))
        return out

    def _update_each(self, inputs: dict[Hashable, dict]) -> dict[Hashable, dict]:
        """Every learner's own update at one torch thread, the learners dealt in turn to ``min(learners, threads)``
        lanes: the first lane on this thread, the others on a pool's."""
        threads = torch.get_num_threads()
        keys = list(self.learners)
        lanes = [keys[n::threads] for n in range(min(len(keys), threads))]

        def run(lane: list[Hashable]) -> dict[Hashable, dict]:
            torch.set_num_threads(1)
            return {k: self.learners[k].update(self.learners[k].value(inputs[k])) for k in lane}

        if len(lanes) > 1 and self._pool is None:
            self._pool = ThreadPoolExecutor(len(lanes) - 1, thread_name_prefix="learner")
        futures = [self._pool.submit(run, lane) for lane in lanes[1:]]
        try:
            out = run(lanes[0])
        finally:
            torch.set_num_threads(threads)
        for future in futures:
            out.update(future.result())
        return {k: out[k] for k in keys}

    # ------------------------------------------------------ optimizers, end
    def sync_optimizers(self) -> None:
        """Each learner that updates in a process of its own: its optimizer state fetched from there (whose it is)."""
        for i, process in self._processes.items():
            self.learners[i].optimizer.load_state_dict(process.optimizer_state())

    def close(self) -> None:
        """End the threads and processes the learners update on; the next update starts them again."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        self._close_processes()

    def _close_processes(self, keep_state: bool = True) -> None:
        """End the learners' update processes, each learner's optimizer state brought back from its own (a process
        in an update, or one that died, has none to give: it is ended, and the first such error raised after);
        ``keep_state=False``: killed at once, their states lost (an update cut short)."""
        processes, self._processes = self._processes, {}
        errors = []
        for i, process in processes.items():
            if not keep_state:
                process.kill()
                continue
            try:
                self.learners[i].optimizer.load_state_dict(process.optimizer_state())
            except RuntimeError as error:
                errors.append(error)
            finally:
                process.close()
        if errors:
            raise errors[0]
