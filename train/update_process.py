"""A learner's PPO update in a process of its own, for learners that update side by side on a CPU.

Two learners updating on two threads of one process hand Python's GIL to each other at every tensor
operation: each hand-over is a context switch, about 900-1,100 of them for two updates at the paper's
batch, and the updates take about 15% longer than on two processes, which take about what one takes alone
(``bench/bench_update.py`` prints both; docs/PERFORMANCE.md, "Each learner's update in a process of its own").

The process is forked from the update processes' own fork server (``_SERVER``, one for the trainer's process: a
``multiprocessing.forkserver.ForkServer``, a fresh interpreter that loaded ``train.update_server`` and ran nothing
else; not multiprocessing's shared one, which anything else in the trainer's process may have started with other
modules), never from the trainer: a trainer's process may hold threads in the middle of anything at the moment it
forks (MKL's buffer allocator, OpenMP's pools, a Ray client's gRPC threads), and a process forked from it could wait
for ever on a lock that no thread of its own will release
(on an Intel Xeon, after a test process had run Ray, one spun in MKL's allocator at its first matrix product).
The process runs a function of this module, never the script that trains (so a script needs no
``if __name__ == "__main__"`` guard: ``_ForkserverPopen``). It holds a ``Learner`` on the same network: its
parameters are moved to shared memory first and sent to the process as shared memory, so its updates are the
trainer's network's, and the rollout's network views (in shared memory too, sent when the process starts and
written in place by every rollout) are read where they lie: an update sends their step count, not their
memory (a view made after the process started goes by value). Everything else the update reads or
changes goes both ways by value: the rollout's small tensors and the bootstrap value go out, the learner's
random generator goes out and comes back, and the statistics come back. The optimizer's state lives in the
process; ``optimizer_state`` fetches it (for a checkpoint, and when the process ends) and ``load_optimizer``
sets it. The server starts once a trainer's process, each process from it in a fraction of a second
(``bench/bench_update_start.py``). The process runs the same operations on the same inputs at one torch
thread, as the trainer's thread would: the results are the same bit for bit
(``tests/test_train.py`` checks). Where it cannot start (not Linux, no shared memory left, no process to be
had, a daemonic parent), ``Unavailable`` says why and the trainer updates on threads.

The trainer waits for an answer as long as the process works (``train.stalls``): a process that has died is an
error at once (its exit code named), and one that is alive but has used no CPU for ``STALL_S`` while an answer is
owed (blocked: an update waits on nothing) is stopped with SIGABRT, which makes it write every thread's stack to
stderr (``faulthandler``) as it ends, and is an error naming it. The fork server is held to the same
rule while a process is asked of it: one that has used no CPU for ``STALL_S`` before it forks (its start blocked) is
ended the same way, and the trainer updates on threads (``Unavailable``), as every trainer of the process does
from then on. A run never hangs on its update process.
"""

from __future__ import annotations

import contextlib
import faulthandler
import io
import multiprocessing
import os
import resource
import signal
import sys
import traceback
from multiprocessing import connection, forkserver, popen_forkserver, reduction, spawn, util
from multiprocessing.context import ForkServerProcess, set_spawning_popen

import numpy as np
import torch

from train.learner import Learner
from train.stalls import ABORT_WAIT_S, abort, reaped, working

AVAILABLE = sys.platform.startswith("linux")
"""Whether update processes start here: from a fork server, on Linux (macOS's system libraries are not safe to
use after a fork; Windows has none)."""

STALL_S = 120.0
"""Seconds an update process may use no CPU while an answer is owed before it is taken as blocked (an update at
the paper's batch takes about 0.2 s of CPU; a process that only waits for a core still gets some)."""


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
    """``learner``'s updates in a process of its own (from the fork server; ``close`` ends it, ``kill`` at once)."""

    def __init__(self, learner: Learner, stall_s: float = STALL_S):
        if learner.device.type != "cpu" or not AVAILABLE:
            raise Unavailable(f"an update process is forked (Linux) and shares a CPU learner's memory; "
                              f"{learner.name} is on {learner.device}, on {sys.platform}")
        if multiprocessing.current_process().daemon:
            raise Unavailable("this trainer runs in a daemonic process, which may not start processes")
        if _SERVER_BLOCKED:
            raise Unavailable(f"no process for the {learner.name} learner's update ({_SERVER_BLOCKED} before)")
        self.name, self.stall_s = learner.name, stall_s
        try:  # before the start: the process's network and views are these, where they lie
            learner.model.share_memory()
            share_views(learner)
        except (RuntimeError, OSError) as error:  # e.g. a container's small /dev/shm
            raise Unavailable(f"no shared memory for the {learner.name} learner ({error})") from error
        self.conn, theirs = multiprocessing.Pipe()
        lr = learner.optimizer.param_groups[0]["lr"]
        self._inherited = dict(learner.views)  # the views the process holds from its start (by name)
        self.process = _UpdateServer(target=_serve, name=f"update-{learner.name}", daemon=True, stall_s=stall_s,
                                     args=(theirs, learner.model, learner.ppo, learner.weights, lr, learner.name,
                                           self._inherited, _Fd(2)))  # (its stderr: the trainer's now)
        self.pending = False  # an update started and its answer not yet read
        try:
            sys.stderr.flush()
            self.process.start()
        except (OSError, EOFError, ValueError) as error:  # no process to be had (a limit on processes, no memory,
            self.conn.close()                               # a fork server that could not start)
            raise Unavailable(f"no process for the {learner.name} learner's update ({error})") from error
        finally:
            theirs.close()
        try:
            self._receive()  # ready: its learner made (waited for as any answer is: never for ever)
            self.load_optimizer(learner.optimizer.state_dict())
        except BaseException:
            self.kill()
            raise

    def start(self, learner: Learner, bootstrap_value: torch.Tensor) -> None:
        """Start ``learner.update(bootstrap_value)`` at one torch thread; ``finish`` waits for it."""
        self._idle("start an update")
        share_views(learner)
        batch = learner.stacked()
        batch["view"] = {k: (learner.steps if self._inherited.get(k) is learner.views[k] else _out(v))
                         for k, v in batch["view"].items()}  # (the step count of a view the process holds)
        self._send("update", {"batch": _out(batch), "bootstrap": _out(bootstrap_value),
                              "initial_state": _out(learner.initial_state),
                              "generator": _out(learner.generator.get_state())})
        self.pending = True

    def finish(self, learner: Learner) -> dict[str, float]:
        """The update's statistics; ``learner``'s generator continues where the update left it."""
        reply = self._receive()  # (interrupted here, the answer is still owed: ``pending`` stays set)
        self.pending = False
        learner.generator.set_state(_in(reply["generator"]))
        return reply["stats"]

    def optimizer_state(self) -> dict:
        self._idle("read its optimizer state")
        self._send("optimizer_state", None)
        return _in(self._receive())

    def load_optimizer(self, state: dict) -> None:
        self._idle("set its optimizer state")
        self._send("load_optimizer", _out(state))
        self._receive()

    @property
    def alive(self) -> bool:
        return self.process.is_alive()

    def close(self) -> None:
        """Ask the process to end (at once if it is in an update: ``kill``)."""
        if self.pending:
            return self.kill()
        if self.process.is_alive():
            try:
                self._send("stop", None)
            except RuntimeError:  # gone already
                pass
        self.process.join(10)
        self.kill()

    def kill(self) -> None:
        """End the process now (an update it is in is lost with it)."""
        if self.process.is_alive():
            self.process.kill()
        self.process.join(ABORT_WAIT_S)  # (bounded: a process stuck in the kernel is left, never waited on for ever)
        self.conn.close()

    def _idle(self, what: str) -> None:
        if self.pending:
            raise RuntimeError(f"the {self.name} learner's update process is still in an update: cannot {what}")

    def _send(self, what: str, payload) -> None:
        try:
            self.conn.send((what, payload))
        except (OSError, EOFError) as error:
            raise RuntimeError(self._stopped(error)) from error

    def _receive(self):
        self._wait()
        try:
            ok, answer = self.conn.recv()
        except (OSError, EOFError) as error:
            raise RuntimeError(self._stopped(error)) from error
        if not ok:
            raise RuntimeError(f"the {self.name} learner's update process failed:\n{answer}")
        return answer

    def _wait(self) -> None:
        """Until an answer (or the end of the pipe) is there to read; a process that died, or that has used no CPU
        for ``stall_s``, raises (see the module docstring)."""
        if working(self.conn.poll, self.process.pid, self.stall_s, ended=lambda: not self.process.is_alive()):
            if self.conn.poll():  # (its answer, or the end of the pipe, came, perhaps as it ended)
                return
            raise RuntimeError(self._stopped(EOFError("no answer")))
        abort(self.process.pid, ended=lambda within: self.process.join(within) or not self.process.is_alive())
        ending = (f"stopped (exit code {self.process.exitcode}" if self.process.exitcode is not None else
                  f"sent SIGKILL, still not ended after {2 * ABORT_WAIT_S:g} s (pid {self.process.pid}")
        raise RuntimeError(f"the {self.name} learner's update process used no CPU for {self.stall_s:g} s "
                           f"while its answer was owed: {ending}; its threads' stacks are on stderr)")

    def _stopped(self, error: Exception) -> str:
        self.process.join(1)
        return (f"the {self.name} learner's update process stopped (exit code {self.process.exitcode}): "
                f"{type(error).__name__}")


class _ForkserverPopen(popen_forkserver.Popen):
    """The fork server's start of a process, less the script that trains: ``popen_forkserver.Popen._launch``
    (Python 3.11-3.13) with the preparation's ``init_main_from_path`` and ``init_main_from_name`` left out, so
    the process imports this module (it runs ``_serve``) and never runs the trainer's ``__main__`` again."""

    def _launch(self, process_obj):
        prep_data = {k: v for k, v in spawn.get_preparation_data(process_obj._name).items()
                     if k not in ("init_main_from_path", "init_main_from_name")}
        buf = io.BytesIO()
        set_spawning_popen(self)
        try:
            reduction.dump(prep_data, buf)
            reduction.dump(process_obj, buf)
        finally:
            set_spawning_popen(None)
        self.sentinel, w = _SERVER.connect_to_new_process(self._fds)  # (starts the server if it is not running)
        _parent_w = os.dup(w)  # (the process's sentinel of its parent, as the standard library keeps it)
        self.finalizer = util.Finalize(self, util.close_fds, (_parent_w, self.sentinel))
        with open(w, "wb", closefd=True) as f:
            f.write(buf.getbuffer())
        self.pid = _forked_pid(self.sentinel, process_obj.stall_s)


class _UpdateServer(ForkServerProcess):
    """An update process, started by ``_ForkserverPopen`` from ``_SERVER``, which loads ``train.update_server``
    before its first fork, so that each process starts with torch imported and its optimizer's first use behind
    it; ``stall_s`` bounds the server's answer as it bounds the process's."""

    def __init__(self, *args, stall_s: float, **kwargs):
        super().__init__(*args, **kwargs)
        self.stall_s = stall_s

    @staticmethod
    def _Popen(process_obj):
        return _ForkserverPopen(process_obj)


def _new_server() -> forkserver.ForkServer:
    server = forkserver.ForkServer()
    server.set_forkserver_preload(["train.update_server"])  # (read when the server starts: at the first process)
    return server


_SERVER = _new_server()
"""The fork server of this process's update processes, one for every trainer of the process (started at the
first process asked of it; it ends with this process)."""

_SERVER_BLOCKED: str | None = None
"""Why this process's fork server was ended as blocked, if it was: no update process starts here again (a server
that blocks at its start would block again, and each trainer would wait ``stall_s`` to learn it)."""


def _forget_server() -> None:  # a process forked from the trainer (not from the server) starts its own server
    global _SERVER
    _SERVER = _new_server()


os.register_at_fork(after_in_child=_forget_server)


def _forked_pid(sentinel: int, stall_s: float) -> int:
    """The pid of the process ``_SERVER`` forks for a request whose status pipe is ``sentinel``, read as long as the
    server works. A server that has used no CPU for ``stall_s`` (its start blocked) is ended (``_end_server``) and
    raises ``OSError``; one that ended raises ``EOFError`` (the standard library's)."""
    global _SERVER, _SERVER_BLOCKED
    server = _SERVER._forkserver_pid
    if not working(lambda timeout: bool(connection.wait([sentinel], timeout)), server, stall_s):
        blocked, _SERVER = _SERVER, _new_server()
        _SERVER_BLOCKED = (f"the update processes' fork server (pid {server}) used no CPU for {stall_s:g} s before "
                           f"forking: stopped (its threads' stacks are on stderr)")
        _end_server(blocked)
        raise OSError(_SERVER_BLOCKED)
    return forkserver.read_signed(sentinel)


def _end_server(server: forkserver.ForkServer) -> None:
    """End the fork server ``server``, found blocked: SIGABRT, whose ``faulthandler`` (enabled by the first lines of
    ``train.update_server``) writes its threads' stacks to stderr, then SIGKILL (``train.stalls.abort``). Processes
    it forked before lose their sentinel with it (they end when their trainer closes their pipe)."""
    pid = server._forkserver_pid
    abort(pid, ended=lambda within: reaped(pid, within))
    with contextlib.suppress(OSError):
        os.close(server._forkserver_alive_fd)
    with contextlib.suppress(OSError):  # (its socket's file, left in the temporary folder otherwise)
        os.unlink(server._forkserver_address)


class _Fd:
    """A file descriptor of the trainer's, sent to the process with it (the fork server's way of sending one)."""

    def __init__(self, fd: int):
        self.fd = fd

    def __reduce__(self):
        return _Fd._detach, (reduction.DupFd(self.fd),)  # (pickled while the process starts: sent with it)

    @staticmethod
    def _detach(fd) -> int:
        return fd.detach()


def share_views(learner: Learner) -> None:
    """The learner's rollout storage in shared memory (moved once, then kept: the process reads it in place)."""
    for view in learner.views.values():
        view.share_memory_()


def _serve(conn, model, ppo, weights, lr: float, name: str, views: dict, stderr: int) -> None:
    """The process: a learner on the shared network, answering ``UpdateProcess``'s requests until ``stop`` or
    until the trainer's end of the pipe closes (the trainer ended). ``views``: the rollout's views when it
    started, in shared memory, which an update names by its step count; ``stderr``: where the trainer's stderr
    went when it started, this process's from now on."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl+C is the trainer's to handle: it ends this process
    if stderr != 2:
        os.dup2(stderr, 2)
        os.close(stderr)
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # (a SIGABRT writes its stacks, not a core of shared memory)
    faulthandler.enable(all_threads=True)  # a SIGABRT from a trainer that finds it blocked: its stacks to stderr
    torch.set_num_threads(1)  # one thread, as the trainer's thread would update
    learner = Learner(model, ppo, weights, lr, seed=0, device=torch.device("cpu"), name=name)
    conn.send((True, None))  # ready
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
                batch = _in(payload["batch"])
                batch["view"] = {k: views[k][:v] if isinstance(v, int) else v for k, v in batch["view"].items()}
                stats = learner.update_on(batch, _in(payload["bootstrap"]))
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
