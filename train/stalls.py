"""Waiting on a child process that owes an answer, and ending one found blocked.

A process that works uses CPU; one that has used none for a while though an answer is owed waits on nothing and is
taken as blocked (``working``). A blocked process is ended with SIGABRT first, which makes a process that enabled
``faulthandler`` write every thread's stack to stderr as it ends, then SIGKILL, and every wait is bounded
(``abort``). Linux only (``/proc/PID/stat``). ``train.update_process`` holds its update processes and their fork
server to this rule.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time

ABORT_WAIT_S = 10.0
"""Seconds a blocked process is given to end after SIGABRT, and again after SIGKILL (``abort``); one stuck in the
kernel beyond both is left, never waited on for ever."""


def working(ready, pid: int, stall_s: float, ended=lambda: False) -> bool:
    """Wait until ``ready(timeout)`` says there is something to read, or ``ended()``, while process ``pid`` works: true
    then; false once ``pid`` has used no CPU for ``stall_s`` (blocked)."""
    cpu, still, last = cpu_ticks(pid), 0.0, time.monotonic()
    while not ready(min(1.0, stall_s)):
        if ended():
            return True
        now, clock = cpu_ticks(pid), time.monotonic()
        # (at most 2 s a pass: a trainer stopped itself, by Ctrl+Z or a suspended job, counts no stall)
        still, last = (0.0 if now != cpu else still + min(clock - last, 2.0)), clock
        cpu = now
        if still >= stall_s:
            return False
    return True


def abort(pid: int, ended) -> None:
    """Stop the process ``pid``, found blocked: SIGABRT, whose ``faulthandler`` writes its threads' stacks to stderr
    as it ends, then SIGKILL if ``ended(ABORT_WAIT_S)`` (which waits at most that many seconds for it to end) is
    false; ``ended`` is asked once more after SIGKILL, so every wait is bounded (a process stuck in the kernel is
    left)."""
    with contextlib.suppress(ProcessLookupError, PermissionError):  # (ended meanwhile; its pid no longer ours)
        os.kill(pid, signal.SIGABRT)
        os.kill(pid, signal.SIGCONT)  # (a stopped process takes the signal once continued)
    if ended(ABORT_WAIT_S):
        return
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.kill(pid, signal.SIGKILL)  # (a stopped process takes it as it is)
    ended(ABORT_WAIT_S)


def reaped(pid: int, within: float) -> bool:
    """Whether the child ``pid`` ended within ``within`` seconds (waited for: reaped), or was already gone."""
    end = time.monotonic() + within
    while True:
        try:
            if os.waitpid(pid, os.WNOHANG)[0]:
                return True
        except ChildProcessError:  # (reaped elsewhere)
            return True
        if time.monotonic() >= end:
            return False
        time.sleep(0.05)


def cpu_ticks(pid: int) -> int:
    """The CPU time process ``pid`` has used, user and system, in clock ticks (``/proc/PID/stat``); -1 once it is
    gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()  # (after the command's name, which may hold spaces)
    except OSError:
        return -1
    return int(fields[11]) + int(fields[12])  # utime, stime: the stat file's 14th and 15th fields
