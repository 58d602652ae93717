"""Follower inference in a process of its own.

Every policy pool's policy lives in one worker process; the server's inference thread sends it
a batch and waits on the pipe (without the GIL) for the actions. A batched call then never waits
for the event loop to hand back the GIL between torch operations, and the event loop never waits
for inference: the two share no interpreter lock, only the CPUs.

If the worker dies (killed, out of memory), the call that finds it dead fails and starts a new
one at once; each pool's policy is rebuilt there when next used. Until the new process has
loaded it (imports, and a network's weights: a second or more), that pool's calls miss their
deadline and its games take the documented fallback move; then they go on, each follower's
belief starting afresh. A process that dies before it has answered a call (it cannot start: a
broken install, no memory) is started again only after a wait that doubles with each such death
(``backoff`` seconds, then twice that, up to a minute); calls meanwhile fail at once.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
import time
from itertools import count

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput

log = logging.getLogger("colorgrid.server")


class InferenceLost(RuntimeError):
    """The worker process ended during a call."""


class InferenceError(RuntimeError):
    """A policy failed in the worker in a way other than a bad request (that is a ``ValueError``)."""


class InferenceWorker:
    """The worker process and the pipe to it. ``call`` is made from one thread at a time (the hub's inference
    thread); a lock keeps requests and replies paired even if two threads call."""

    MAX_BACKOFF = 60.0

    def __init__(self, target=None, backoff: float = 0.5, clock=time.monotonic):
        self._target = target or serve  # what the process runs (a module-level function of its pipe's end)
        self._clock = clock  # seconds, for the wait after failed starts (a test may give its own)
        self._lock = threading.Lock()
        self._process = None
        self._conn = None
        self.generation = 0  # counts the processes started: a policy built in an older one must be rebuilt
        self.closed = False
        self.backoff = backoff
        self.failed_starts = 0  # processes in a row that died before answering a call
        self._answered = False
        self._retry_at = 0.0

    def _ensure(self, op: str) -> None:
        """A running process for ``op``; if it had died, a new one, and ``InferenceLost`` unless ``op`` builds."""
        if self._process is not None and self._process.is_alive():
            return
        lost = self._process is not None
        self._start()
        if lost and op != "build":  # what this call meant died with the old process
            raise InferenceLost(f"the inference process had ended before {op!r}; a new one started")

    def _start(self) -> None:
        if self._process is not None:
            self._conn.close()
            self.failed_starts = 0 if self._answered else self.failed_starts + 1
            doublings = min(self.failed_starts - 1, 30)  # past the cap anyway; a larger power would overflow
            wait = min(self.MAX_BACKOFF, self.backoff * 2 ** doublings) if self.failed_starts else 0.0
            self._retry_at = self._clock() + wait
            log.error("the inference process ended (exit code %s); %s", self._process.exitcode,
                      f"it had not started: trying again in {wait:.1f} s" if wait else "starting a new one")
            self._process = self._conn = None
        if self._clock() < self._retry_at:
            raise InferenceLost(f"the inference process failed to start {self.failed_starts} time(s) in a row; next "
                                f"try in {self._retry_at - self._clock():.1f} s")
        ctx = multiprocessing.get_context("spawn")  # the server has threads: forking it would copy held locks
        parent, child = ctx.Pipe()
        self._process = ctx.Process(target=self._target, args=(child,), name="colorgrid-inference", daemon=True)
        self._process.start()
        child.close()
        self._conn = parent
        self._answered = False
        self.generation += 1

    def call(self, op: str, *args):
        """Run ``op`` in the worker and return its result; the worker's own error is raised here as
        ``ValueError`` with its message, a dead worker as ``InferenceLost``."""
        with self._lock:
            if self.closed:
                raise InferenceLost("the inference process was stopped")
            self._ensure(op)
            try:
                self._conn.send((op, args))
                status, value = self._conn.recv()
            except (EOFError, OSError) as err:
                self._process.join(1.0)
                if not self._process.is_alive():
                    try:
                        self._start()  # a new process loads while the games take the fallback move
                    except InferenceLost:  # or, if this one never started, after a wait
                        pass
                raise InferenceLost(f"the inference process ended during {op!r} ({type(err).__name__})") from None
            self._answered = True
            self.failed_starts = 0
        if status == "error":
            kind, message = value
            raise (ValueError if kind == "ValueError" else InferenceError)(message)
        return value

    @property
    def pid(self) -> int | None:
        return self._process.pid if self._process is not None else None

    def stop(self, timeout: float = 5.0) -> None:
        """End the process: asked to stop once any call in flight is done, killed if that takes over ``timeout``."""
        self.closed = True
        locked = self._lock.acquire(timeout=timeout)
        try:
            if self._process is None:
                return
            if locked:
                try:
                    self._conn.send(("stop", ()))
                except OSError:
                    pass
                self._process.join(timeout)
            if self._process.is_alive():
                self._process.kill()
                self._process.join(timeout)
        finally:
            if locked:
                self._lock.release()


_ids = count()


class RemotePolicy(Policy):
    """A policy built and run in the worker, behind the ``Policy`` interface the policy pools use."""

    def __init__(self, worker: InferenceWorker, name: str, role: str | None):
        self.worker, self.name, self.role = worker, name, role
        self.key = next(_ids)
        self.built_in = None  # the worker generation holding this policy
        self.description: dict = {}

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        self._build()

    def _build(self) -> None:
        self.description = self.worker.call("build", self.key, self.name, self.role, self.config.to_dict(),
                                            self.num_envs, self.agent_index, self.seed)
        self.built_in = self.worker.generation  # the process that answered (a call starts one if none runs)

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        if self.built_in != self.worker.generation:  # the worker was restarted: this policy starts afresh
            self._build()
        actions, probs = self.worker.call("act", self.key, inp, None if rows is None else np.asarray(rows))
        if self.built_in != self.worker.generation:  # it died and came back within the call
            raise InferenceLost("the inference process was restarted during the call")
        return PolicyOutput(actions, probs)

    def describe(self) -> dict:
        return dict(self.description)

    def describe_row(self, row: int) -> dict:
        if self.built_in != self.worker.generation:  # a restarted worker holds nothing of this row's game
            return self.describe()
        return self.worker.call("describe_row", self.key, int(row))

    def close(self) -> None:
        if self.built_in == self.worker.generation and not self.worker.closed:
            try:
                self.worker.call("drop", self.key)
            except (InferenceLost, ValueError):
                pass
        self.built_in = None  # used again after all (a game attached meanwhile): built again first


def serve(conn) -> None:
    """The worker's loop: build, act, drop, until ``stop`` or the server's end of the pipe closes."""
    import signal
    import sys

    from colorgrid.policies import make_policy

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl+C is the server's to handle: it stops this process
    policies: dict[int, Policy] = {}
    while True:
        try:
            op, args = conn.recv()
        except (EOFError, OSError):
            return
        if op == "stop":
            return
        try:
            if op == "build":
                key, name, role, config, num_envs, agent_index, seed = args
                policy = make_policy(name, role=role)
                policy.reset(EnvConfig.from_dict(config), num_envs, agent_index=agent_index, seed=seed)
                policies[key] = policy
                reply = policy.describe()
                if "torch" in sys.modules:  # a trained network: one core for it, no torch threads spinning
                    import torch

                    torch.set_num_threads(1)
            elif op == "act":
                key, inp, rows = args
                out = policies[key].act(inp, rows=rows)
                reply = (out.actions, out.goal_probs)
            elif op == "describe_row":
                key, row = args
                reply = policies[key].describe_row(row)
            elif op == "ping":  # ready: imports done, serving
                reply = None
            elif op == "drop":
                policies.pop(args[0], None)
                reply = None
            else:
                raise ValueError(f"unknown request {op!r}")
        except Exception as err:  # the policy's own error goes back to the caller, and the worker serves on
            conn.send(("error", (type(err).__name__, f"{type(err).__name__}: {err}" if not isinstance(
                err, ValueError) else str(err))))
            continue
        conn.send(("ok", reply))
