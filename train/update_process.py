"""A learner's PPO update in a process of its own, for learners that update side by side on a CPU.

Two learners updating on two threads of one process hand Python's GIL to each other at every tensor
operation: each hand-over is a context switch, about 1,300 of them per update at the paper's batch, and
the updates take about 20% longer than one alone; on two processes they take what one takes alone
(``bench/bench_update.py``; docs/PERFORMANCE.md, "Each learner's update in a process of its own").

The process is forked from the trainer (so a script that trains needs no ``__main__`` guard) and holds a
``Learner`` on the same network: its parameters are moved to shared memory first, so its updates are the
trainer's network's, and the rollout's network views (in shared memory too) are read where they lie.
Everything else the update reads or changes goes both ways by value: the rollout's small tensors and the
bootstrap value go out, the learner's random generator goes out and comes back, and the statistics come
back. The optimizer's state lives in the process; ``optimizer_state`` fetches it (for a checkpoint, and
when the process ends) and ``load_optimizer`` sets it. The process runs the same operations on the same
inputs at one torch thread, as the trainer's thread would: the results are the same bit for bit
(``tests/test_train.py`` checks). Where it cannot start (no fork, no shared memory left), ``Unavailable``
says why and the trainer updates on threads.
"""

from __future__ import annotations

import multiprocessing
import signal
import traceback

import numpy as np
import torch

from train.learner import Learner

AVAILABLE = "fork" in multiprocessing.get_all_start_methods()
"""Whether this platform forks processes (Linux, macOS; not Windows). A forked process needs no import of the
script that trains (a spawned one would run a script without an ``if __name__ == "__main__"`` guard again)."""


def _out(t):
    """A rollout entry for the pipe: network views (in shared memory) as they are, small tensors as arrays."""
    if isinstance(t, dict):
        return {k: _out(v) for k, v in t.items()}
    if isinstance(t, tuple):
        return tuple(_out(v) for v in t)
    return t.numpy() if isinstance(t, torch.Tensor) and not t.is_shared() else t


def _in(t):
    if isinstance(t, dict):
        return {k: _in(v) for k, v in t.items()}
    if isinstance(t, tuple):
        return tuple(_in(v) for v in t)
    return torch.from_numpy(t) if isinstance(t, np.ndarray) else t


class Unavailable(RuntimeError):
    """No update process for this learner here (no fork, not on the CPU, or no shared memory left)."""


class UpdateProcess:
    """``learner``'s updates in a process of its own (forked here; ``close`` ends it)."""

    def __init__(self, learner: Learner):
        if learner.device.type != "cpu" or not AVAILABLE:
            raise Unavailable(f"an update process is forked and shares a CPU learner's memory; {learner.name} is on "
                              f"{learner.device}, and this platform {'forks' if AVAILABLE else 'does not fork'}")
        self.name = learner.name
        try:  # before the fork: the process's network is this one
            learner.model.share_memory()
            share_views(learner)
        except (RuntimeError, OSError) as error:  # e.g. a container's small /dev/shm
            raise Unavailable(f"no shared memory for the {learner.name} learner ({error})") from error
        context = multiprocessing.get_context("fork")
        self.conn, theirs = context.Pipe()
        lr = learner.optimizer.param_groups[0]["lr"]
        self.process = context.Process(target=_serve, name=f"update-{learner.name}", daemon=True,
                                       args=(theirs, self.conn, learner.model, learner.ppo, learner.weights, lr,
                                             learner.name))
        self.process.start()
        theirs.close()
        self.pending = False  # an update started and not yet finished
        self.load_optimizer(learner.optimizer.state_dict())

    def start(self, learner: Learner, bootstrap_value: torch.Tensor) -> None:
        """Start ``learner.update(bootstrap_value)`` at one torch thread; ``finish`` waits for it."""
        share_views(learner)
        self._send("update", {"batch": _out(learner.stacked()), "bootstrap": _out(bootstrap_value),
                              "initial_state": _out(learner.initial_state),
                              "generator": _out(learner.generator.get_state())})
        self.pending = True

    def finish(self, learner: Learner) -> dict[str, float]:
        """The update's statistics; ``learner``'s generator continues where the update left it."""
        self.pending = False
        reply = self._receive()
        learner.generator.set_state(_in(reply["generator"]))
        return reply["stats"]

    def optimizer_state(self) -> dict:
        if self.pending:  # (the trainer failed between start and finish): the update's answer comes first
            self.pending = False
            try:
                self._receive()
            except RuntimeError:
                pass
        self._send("optimizer_state", None)
        return _in(self._receive())

    def load_optimizer(self, state: dict) -> None:
        self._send("load_optimizer", _out(state))
        self._receive()

    @property
    def alive(self) -> bool:
        return self.process.is_alive()

    def close(self) -> None:
        if self.process.is_alive():
            try:
                self._send("stop", None)
            except OSError:
                pass
        self.process.join(10)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.conn.close()

    def _send(self, what: str, payload) -> None:
        try:
            self.conn.send((what, payload))
        except (OSError, EOFError) as error:
            raise RuntimeError(self._stopped(error)) from error

    def _receive(self):
        try:
            ok, answer = self.conn.recv()
        except (OSError, EOFError) as error:
            raise RuntimeError(self._stopped(error)) from error
        if not ok:
            raise RuntimeError(f"the {self.name} learner's update process failed:\n{answer}")
        return answer

    def _stopped(self, error: Exception) -> str:
        self.process.join(1)
        return (f"the {self.name} learner's update process stopped (exit code {self.process.exitcode}): "
                f"{type(error).__name__}")


def share_views(learner: Learner) -> None:
    """The learner's rollout storage in shared memory (moved once, then kept: the process reads it in place)."""
    for view in learner.views.values():
        view.share_memory_()


def _serve(conn, trainers_end, model, ppo, weights, lr: float, name: str) -> None:
    """The process: a learner on the shared network, answering ``UpdateProcess``'s requests until ``stop`` or
    until the trainer's end of the pipe closes (the trainer ended)."""
    trainers_end.close()  # (forked with it): the trainer's end closing is then this end's EOF
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl+C is the trainer's to handle: it ends this process
    torch.set_num_threads(1)  # one thread: OpenMP's threads do not survive a fork, and none are started here
    learner = Learner(model, ppo, weights, lr, seed=0, device=torch.device("cpu"), name=name)
    while True:
        try:
            what, payload = conn.recv()
        except (EOFError, OSError):
            return
        if what == "stop":
            return
        try:
            if what == "update":
                learner.generator.set_state(_in(payload["generator"]))
                learner.initial_state = _in(payload["initial_state"])
                stats = learner.update_on(_in(payload["batch"]), _in(payload["bootstrap"]))
                answer = {"stats": stats, "generator": _out(learner.generator.get_state())}
            elif what == "optimizer_state":
                answer = _out(learner.optimizer.state_dict())
            elif what == "load_optimizer":
                answer = learner.optimizer.load_state_dict(_in(payload))
            else:
                raise ValueError(f"unknown request {what!r}")
        except Exception:  # the trainer raises it with this traceback
            conn.send((False, traceback.format_exc()))
            continue
        conn.send((True, answer))
