"""The launcher: the parent process of ``colorgrid play|study run --processes N`` (or ``--backends``).

It starts N backend processes (``server.cluster.process``: uvicorn, one worker each, each with its own inference
process) on free loopback ports, writes ``cluster.json`` and ``haproxy.cfg`` into the study's folder (the
recordings folder in free play), starts HAProxy on the public address once every backend is ready, and then
watches them: a child that dies is started again after a short wait (1 s, doubling while it keeps dying soon
after its start, at most 30 s). On SIGTERM or Ctrl+C it tells HAProxy to stop taking connections (it keeps those
open, and stops checking the backends), stops the backends (each saves its live games and tells its players over
those connections), then waits for HAProxy to end; no child outlives it (a backend stops itself when its launcher
is gone, HAProxy is stopped by the kernel then).

Its output is what a researcher needs: each backend ready, HAProxy ready, a child that died and was started
again, HAProxy's word that a backend is down or up again, the stop; the backends log their requests but not
HAProxy's health checks (``server.run.named_logs``), and HAProxy's lines come through the launcher, in words.

From Python (a load bench)::

    cluster = Cluster.local(ServerSettings(port=0, replays_dir=folder), processes=3, folder=folder)
    with cluster:              # start(): every backend ready, HAProxy answering on cluster.url
        ...                    # cluster.poll() now and then restarts a backend that died
"""

from __future__ import annotations

import ctypes
import dataclasses
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import server
from server.cluster.haproxy import HEALTH_CHECK, check_config, haproxy_binary, haproxy_said, proxy_config
from server.cluster.plan import (CLUSTER_FILE, PROXY_FILE, RESTARTS_ENV, ClusterPlan, Membership, check_processes,
                                 free_port)
from server.cluster.process import BackendSpec
from server.cluster.siblings import ask
from server.settings import ServerSettings

READY_TIMEOUT_S = 180.0
"""How long a backend may take to load its followers at the start (a fresh install compiles the env step)."""
STOP_TIMEOUT_S = 45.0
"""How long a backend may take to stop (saving its games takes at most 30 s, closing its sockets 10 s)."""
PROXY_STOP_TIMEOUT_S = 10.0
"""How long HAProxy may keep connections open once every backend has stopped (it ends with the last one)."""
PR_SET_PDEATHSIG = 1
QUIET_WARNINGS = "ignore:resource_tracker:UserWarning"
"""A backend's warning filter: a backend killed outright leaves its semaphores to its resource tracker, which frees
them and would warn of each "leak" (the launcher says the backend was killed)."""


def die_with(launcher: int):
    """What a child runs before its program (Linux): the kernel sends it SIGTERM when the launcher dies (and it
    stops at once if the launcher died before that was set)."""
    def arm() -> None:
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        except (OSError, AttributeError):  # not Linux: the launcher's own stop is the only one
            return
        if os.getppid() != launcher:
            os.kill(os.getpid(), signal.SIGTERM)
    return arm


def say(text: str) -> None:
    print(f"colorgrid cluster: {text}", flush=True)


class Stopped(Exception):
    """SIGTERM or Ctrl+C came while the cluster was starting."""


class Child:
    """One supervised process: started, watched, started again after a short wait when it dies."""

    FIRST_WAIT_S = 1.0
    MAX_WAIT_S = 30.0
    STABLE_S = 60.0
    """A child that ran this long before it died is started again after the first wait, not a longer one."""

    def __init__(self, name: str, argv: list[str], stdin: bytes | None = None, env: dict | None = None,
                 pre_exec=None, relay=None):
        self.name, self.argv, self.stdin, self.env, self.pre_exec = name, argv, stdin, env, pre_exec
        self.relay = relay  # called with each line of the child's output (read through a pipe); None: its output
        # is the launcher's own
        self.process: subprocess.Popen | None = None
        self.started_at = 0.0
        self.wait_s = self.FIRST_WAIT_S
        self.restart_at: float | None = None
        self.restarts = 0

    def start(self) -> None:
        env = None if self.env is None else {**self.env, RESTARTS_ENV: str(self.restarts)}  # a backend reports it
        output = subprocess.PIPE if self.relay is not None else None
        self.process = subprocess.Popen(self.argv, stdin=subprocess.PIPE if self.stdin is not None else None,
                                        stdout=output, stderr=subprocess.STDOUT if output else None, env=env,
                                        start_new_session=True, preexec_fn=self.pre_exec)
        if self.stdin is not None:
            self.process.stdin.write(self.stdin)
            self.process.stdin.close()
        if self.relay is not None:
            threading.Thread(target=self.read_output, args=(self.process.stdout,), daemon=True,
                             name=f"{self.name}-output").start()
        self.started_at, self.restart_at = time.monotonic(), None

    def read_output(self, stream) -> None:
        for line in iter(stream.readline, b""):
            self.relay(line.decode(errors="replace").rstrip())
        stream.close()

    @property
    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def check(self, now: float | None = None) -> None:
        """Start it again if it died and its wait is over (called every half second by the launcher); ``now``: the
        time (``time.monotonic()``'s clock) a test gives it."""
        now = time.monotonic() if now is None else now
        if self.process is None or self.alive:
            return
        if self.restart_at is None:
            code = self.process.returncode
            ran_s = now - self.started_at
            self.wait_s = self.FIRST_WAIT_S if ran_s >= self.STABLE_S else self.wait_s
            self.restart_at = now + self.wait_s
            how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
            say(f"{self.name} stopped ({how}) after {ran_s:.0f} s; starting it again in {self.wait_s:g} s")
            self.wait_s = min(2 * self.wait_s, self.MAX_WAIT_S)
        elif now >= self.restart_at:
            self.restarts += 1
            try:
                self.start()
            except (OSError, subprocess.SubprocessError) as error:  # no process, or it died before its spec
                self.restart_at = now + self.wait_s
                say(f"{self.name} could not be started again ({error}); trying again in {self.wait_s:g} s")
                self.wait_s = min(2 * self.wait_s, self.MAX_WAIT_S)
                return
            say(f"{self.name} started again (restart {self.restarts}, pid {self.process.pid})")

    def terminate(self) -> None:
        if self.alive:
            self.process.terminate()

    def wait(self, timeout_s: float) -> None:
        """Wait for it to end; past ``timeout_s``, kill it."""
        if self.process is None:
            return
        try:
            self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            say(f"{self.name} did not stop within {timeout_s:g} s: killing it")
            self.process.kill()
            self.process.wait()


class Cluster:
    """Backends on this machine (or elsewhere) and HAProxy in front of them, as one thing to start and stop."""

    def __init__(self, plan: ClusterPlan, settings: ServerSettings, folder: Path, plugin=None, log_level: str = "info",
                 local: bool = True):
        self.plan, self.settings, self.folder, self.plugin, self.log_level = plan, settings, folder, plugin, log_level
        self.binary = haproxy_binary()
        self.plan_file, self.proxy_file = folder / CLUSTER_FILE, folder / PROXY_FILE
        self.backends = [self.backend(m) for m in plan.members] if local else []
        self.proxy = Child("haproxy", [self.binary, "-db", "-f", str(self.proxy_file)], pre_exec=die_with(os.getpid()),
                           relay=self.relay_haproxy)
        self._stop = threading.Event()

    @classmethod
    def local(cls, settings: ServerSettings, processes: int, folder: Path, plugin=None,
              log_level: str = "info") -> Cluster:
        """``processes`` backends on loopback ports of this machine, HAProxy on ``settings``' host and port (a
        free port for 0)."""
        check_processes(processes)
        port = settings.port or free_port(settings.host if settings.host not in ("0.0.0.0", "::") else "127.0.0.1")
        return cls(ClusterPlan.local(settings.host, port, processes), settings, folder, plugin, log_level)

    @classmethod
    def proxy_only(cls, settings: ServerSettings, backends: str, folder: Path, plugin=None) -> Cluster:
        """HAProxy alone, in front of the backends ``--backends`` names (other machines sharing the database and
        the recordings folder; each started with ``--cluster`` and the plan file this writes)."""
        port = settings.port or free_port()
        return cls(ClusterPlan.remote(settings.host, port, backends), settings, folder, plugin, local=False)

    @property
    def url(self) -> str:
        """Where people connect: the proxy."""
        host = {"0.0.0.0": "127.0.0.1", "::": "[::1]"}.get(self.plan.public_host, self.plan.public_host)
        host = f"[{host}]" if ":" in host and not host.startswith("[") else host
        return f"http://{host}:{self.plan.public_port}"

    def backend_settings(self, member) -> ServerSettings:
        """A backend's settings: the user's, listening on its loopback port and answering the public host too."""
        public = self.plan.public_host
        hosts = (*self.settings.allowed_hosts, *([] if public in ("0.0.0.0", "::") else [public]))
        return dataclasses.replace(self.settings, host=member.host, port=member.port,
                                   allowed_hosts=tuple(dict.fromkeys(hosts)))

    def backend(self, member) -> Child:
        spec = BackendSpec(self.backend_settings(member), Membership(self.plan_file, member.name), self.log_level,
                           self.plugin, launcher_pid=os.getpid())
        package_root = str(Path(server.__file__).resolve().parent.parent)  # the child imports this very code
        path = os.pathsep.join(p for p in (package_root, os.environ.get("PYTHONPATH", "")) if p)
        warnings = ",".join(w for w in (os.environ.get("PYTHONWARNINGS", ""), QUIET_WARNINGS) if w)
        return Child(member.name, [sys.executable, "-m", "server.cluster.process"], pickle.dumps(spec),
                     {**os.environ, "PYTHONPATH": path, "PYTHONUNBUFFERED": "1", "PYTHONWARNINGS": warnings})

    @staticmethod
    def relay_haproxy(line: str) -> None:
        said = haproxy_said(line)
        if said is not None:
            say(said)

    def id_params(self) -> tuple[str, ...]:
        return tuple(self.plugin.routing_params) if self.plugin is not None else ()

    def write_files(self) -> None:
        """``cluster.json`` (the backends read it) and ``haproxy.cfg`` (checked by HAProxy) in the folder."""
        self.plan.write(self.plan_file)
        self.proxy_file.write_text(proxy_config(self.plan, self.settings, self.id_params()))
        check_config(self.binary, self.proxy_file)

    # ------------------------------------------------------------ start, watch, stop
    def start(self, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Every backend started and ready, then HAProxy answering; anything started is stopped on failure."""
        self.write_files()
        try:
            for child in self.backends:
                child.start()
            if self.backends:
                say(f"starting {len(self.backends)} backends: " + ", ".join(
                    f"{c.name} (pid {c.process.pid})" for c in self.backends) + "; each loads its followers")
            deadline = time.monotonic() + timeout_s
            for child, member in zip(self.backends, self.plan.members):
                while ask(member.url, HEALTH_CHECK)[0] != 200:
                    if not child.alive:
                        raise ValueError(f"backend {member.name} stopped while starting (exit code "
                                         f"{child.process.returncode}); its output is above")
                    if time.monotonic() > deadline:
                        raise ValueError(f"backend {member.name} was not ready within {timeout_s:g} s")
                    if self._stop.wait(0.2):
                        raise Stopped
                say(f"{member.name} ready on {member.address}")
            self.proxy.start()
            self.wait_for_proxy()
            say(f"haproxy ready on {self.url} (pid {self.proxy.process.pid})")
        except BaseException:
            self.stop()
            raise

    def wait_for_proxy(self, timeout_s: float = 30.0) -> None:
        """HAProxy answering through to a backend (alone in front of other machines: still running after 0.5 s)."""
        deadline = time.monotonic() + timeout_s
        while True:
            time.sleep(0.1)
            if not self.proxy.alive:
                raise ValueError(f"haproxy stopped at its start (exit code {self.proxy.process.returncode}): is "
                                 f"{self.plan.public_host}:{self.plan.public_port} in use?")
            if self.backends and ask(self.url, HEALTH_CHECK)[0] == 200:
                return
            if not self.backends and time.monotonic() - self.proxy.started_at > 0.5:
                return
            if time.monotonic() > deadline:
                raise ValueError(f"haproxy did not answer on {self.url} within {timeout_s:g} s")

    def poll(self) -> None:
        """Start again any child that died (after its wait); call it from the thread that called ``start``."""
        for child in (*self.backends, self.proxy):
            child.check()

    def stop(self) -> None:
        """The backends first (each saves its live games and tells its players), then HAProxy. HAProxy is told
        first to stop taking connections (a soft stop): it keeps those open, through which the backends tell their
        players, and stops checking the backends, so that their stop is not a failure to it; it ends with the last
        connection."""
        if self.proxy.alive:
            self.proxy.process.send_signal(signal.SIGUSR1)
        for child in self.backends:
            child.terminate()
        for child in self.backends:
            child.wait(STOP_TIMEOUT_S)
        if self.proxy.alive:
            try:
                self.proxy.process.wait(PROXY_STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:  # a connection that the backends' stop did not close
                self.proxy.terminate()
        self.proxy.wait(10)

    def run(self) -> int:
        """Start, watch until SIGTERM or Ctrl+C, stop; the launcher's whole life."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: self._stop.set())
        try:
            self.start()
        except Stopped:  # Ctrl+C while the backends were loading: everything started is stopped already
            return 0
        try:
            while not self._stop.wait(0.5):
                self.poll()
            say("stopping: the backends save their games, then haproxy stops")
        finally:  # whatever ends the watch, no child is left running
            self.stop()
        clean = (0, None, -signal.SIGTERM)  # uvicorn ends with the signal that stopped it, once its games are saved
        failed = [f"{c.name} (exit code {c.process.returncode})" for c in self.backends
                  if c.process is not None and c.process.returncode not in clean]
        say("stopped" + (f"; {', '.join(failed)} did not stop cleanly: see above" if failed else ""))
        return 0

    def __enter__(self) -> Cluster:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
