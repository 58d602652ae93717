"""Who is in a cluster: its backends (a name and an address each) and the address the proxy listens on.

The launcher writes the plan as ``cluster.json`` beside ``haproxy.cfg`` (in the study's folder, or the
recordings folder in free play); every backend reads it to find its siblings. The names are HAProxy's server
names (``b1``, ``b2``, ...). The file also holds a random secret the backends show each other (``secret``):
only a sibling may ask a backend which waiting rooms it holds. It is written readable by its owner alone.
"""

from __future__ import annotations

import json
import os
import secrets
import socket
from dataclasses import dataclass
from pathlib import Path

from colorgrid.files import atomic_path, read_json_object

CLUSTER_FILE = "cluster.json"
PROXY_FILE = "haproxy.cfg"
PROCESSES_PER_CPU = 4
"""More backend processes than this per CPU core only compete for the cores (each runs its games and an inference
process of its own)."""
RESTARTS_ENV = "COLORGRID_BACKEND_RESTARTS"
"""How many times the launcher has started this backend again (set in its environment; its health reports it)."""


@dataclass(frozen=True)
class Member:
    """One backend: its name (HAProxy's server name and routing-cookie value) and where it listens."""

    name: str
    host: str
    port: int

    @property
    def address(self) -> str:
        """``host:port`` (an IPv6 host in brackets)."""
        return f"[{self.host}]:{self.port}" if ":" in self.host else f"{self.host}:{self.port}"

    @property
    def url(self) -> str:
        return f"http://{self.address}"


@dataclass(frozen=True)
class ClusterPlan:
    """The backends of one deployment and the proxy's public address."""

    public_host: str
    public_port: int
    members: tuple[Member, ...]
    secret: str
    """Shown by one backend to another (``Authorization: Bearer``) when it asks which rooms the other holds."""

    @classmethod
    def local(cls, public_host: str, public_port: int, processes: int) -> ClusterPlan:
        """``processes`` backends on free loopback ports of this machine."""
        return cls(public_host, public_port, tuple(Member(f"b{i + 1}", "127.0.0.1", free_port())
                                                   for i in range(processes)), secrets.token_urlsafe(24))

    @classmethod
    def remote(cls, public_host: str, public_port: int, backends: str) -> ClusterPlan:
        """The backends ``--backends host:port,...`` names (other machines, or processes started by hand)."""
        members = tuple(Member(f"b{i + 1}", *parse_address(text.strip()))
                        for i, text in enumerate(backends.split(",")) if text.strip())
        if not members:
            raise ValueError(f"--backends {backends!r} names no backend: expected HOST:PORT,HOST:PORT,...")
        if len({m.address for m in members}) < len(members):
            raise ValueError(f"--backends {backends!r} names a backend twice")
        return cls(public_host, public_port, members, secrets.token_urlsafe(24))

    def write(self, path: Path) -> None:
        """``cluster.json``, atomically, readable by its owner alone (it holds the siblings' secret)."""
        doc = {"public": {"host": self.public_host, "port": self.public_port}, "secret": self.secret,
               "backends": [{"name": m.name, "host": m.host, "port": m.port} for m in self.members]}
        with atomic_path(path, mode=0o600) as tmp:  # private before the secret is in it
            tmp.write_text(json.dumps(doc, indent=2) + "\n")

    @classmethod
    def read(cls, path: Path) -> ClusterPlan:
        """The plan in ``path``; a file that is missing or not a plan is a ``ValueError`` in one line."""
        doc = read_json_object(path, "a cluster plan (a JSON object)")
        try:
            members = tuple(Member(str(b["name"]), str(b["host"]), int(b["port"])) for b in doc["backends"])
            return cls(str(doc["public"]["host"]), int(doc["public"]["port"]), members, str(doc["secret"]))
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"{path}: not a cluster file written by colorgrid ({type(err).__name__}: {err})") from None

    def member(self, name: str | None) -> Member | None:
        return next((m for m in self.members if m.name == name), None)


def parse_address(text: str) -> tuple[str, int]:
    """``host:port`` (``[::1]:9001`` for IPv6) -> ``(host, port)``; a ``ValueError`` naming the problem."""
    host, sep, port = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"--backends: {text!r} is not HOST:PORT (a port in 1..65535)")
    return host, int(port)


def check_processes(processes: int, cpus: int | None = None) -> None:
    """Refuse a number of backend processes that cannot help: fewer than one, or more than the cores can run."""
    cpus = cpus or os.cpu_count() or 1
    most = PROCESSES_PER_CPU * cpus
    if processes < 1:
        raise ValueError(f"--processes must be at least 1, got {processes}")
    if processes > most:
        raise ValueError(f"--processes {processes} is more than this machine can run: at most {most} "
                         f"({PROCESSES_PER_CPU} per CPU core, {cpus} here); for more, run backends on several "
                         "machines (--backends)")


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port nobody listens on now (the backend binds it a moment later)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


@dataclass(frozen=True)
class Membership:
    """This process's place in a cluster: the plan file and, when known, its own name there."""

    plan_file: Path
    name: str | None = None

    def plan(self) -> ClusterPlan:
        """The plan as the file says now (read at each use: a few hundred bytes)."""
        return ClusterPlan.read(self.plan_file)

    @classmethod
    def of(cls, plan_file: Path, port: int) -> Membership:
        """A backend started by hand with ``--cluster FILE``: its name is that of the one backend in the file that
        listens on its port (none when several do: each machine then reports itself under its address)."""
        named = [m.name for m in ClusterPlan.read(plan_file).members if m.port == port]
        return cls(plan_file, named[0] if len(named) == 1 else None)
