"""A PostgreSQL cluster of the tests' own: ``initdb`` in a temporary folder, reached through a Unix socket there (no
TCP port to race other processes for), trust auth.

``PostgresCluster.start()`` finds ``initdb`` and ``pg_ctl`` on PATH, else in Debian's
``/usr/lib/postgresql/<version>/bin`` (``make services`` installs them), and fails in one sentence
when neither has them. ``initdb`` refuses to run as root: as root, the cluster's folder belongs to
the ``postgres`` system user and both commands run as that user (``runuser``). The tests connect
as the role ``colorgrid`` through the socket in the cluster's folder; ``new_database()`` gives each
test a database of its own.
"""

from __future__ import annotations

import glob
import itertools
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

ROLE = "colorgrid"
SUPERUSER = "postgres"
SYSTEM_USER = "postgres"
"""The system user that runs the cluster when the tests run as root."""
DEBIAN_BINARIES = "/usr/lib/postgresql/*/bin"


def binaries() -> Path:
    """The folder holding ``initdb`` and ``pg_ctl``: on PATH, else the newest of Debian's."""
    found = [shutil.which(name) for name in ("initdb", "pg_ctl")]
    if all(found) and Path(found[0]).parent == Path(found[1]).parent:
        return Path(found[0]).parent
    debian = sorted((Path(p) for p in glob.glob(DEBIAN_BINARIES)), key=lambda p: int(p.parent.name)
                    if p.parent.name.isdigit() else 0)
    for folder in reversed(debian):
        if (folder / "initdb").is_file() and (folder / "pg_ctl").is_file():
            return folder
    raise RuntimeError(f"PostgreSQL's initdb and pg_ctl are neither on PATH nor in {DEBIAN_BINARIES}: the study "
                       "tests run on PostgreSQL too; install them with `make services` (Debian's postgresql)")


@dataclass
class PostgresCluster:
    """A running cluster; ``url(database)`` connects as ``ROLE``."""

    folder: Path
    bin: Path
    as_user: list[str]
    port: int = 5432
    """Names the socket file in ``folder`` (``.s.PGSQL.5432``); no TCP port is opened."""
    names: itertools.count = field(default_factory=itertools.count)

    @classmethod
    def start(cls) -> PostgresCluster:
        bin_dir = binaries()
        folder = Path(tempfile.mkdtemp(prefix="colorgrid-pg-"))
        as_user = []
        if os.geteuid() == 0:  # initdb refuses root: the cluster is the postgres user's
            shutil.chown(folder, SYSTEM_USER, SYSTEM_USER)
            as_user = ["runuser", "-u", SYSTEM_USER, "--"]
        cluster = cls(folder, bin_dir, as_user)
        cluster.run("initdb", "-D", str(folder / "data"), "-U", SUPERUSER, "-A", "trust", "-E", "UTF8",
                    "--no-locale", "--no-sync")
        options = (f"-p {cluster.port} -c listen_addresses='' -k {folder} -c max_connections=300 -c fsync=off "
                   "-c synchronous_commit=off -c full_page_writes=off")
        try:
            cluster.run("pg_ctl", "-D", str(folder / "data"), "-l", str(folder / "server.log"), "-o", options,
                        "-w", "-t", "60", "start")
            cluster.sql(f"CREATE ROLE {ROLE} LOGIN")
        except BaseException:
            cluster.stop()
            raise
        return cluster

    def run(self, command: str, *args: str) -> None:
        result = subprocess.run([*self.as_user, str(self.bin / command), *args], check=False, capture_output=True,
                                text=True, timeout=120)
        if result.returncode != 0:
            log = self.folder / "server.log"
            raise RuntimeError(f"{command} failed ({result.returncode}): {result.stderr.strip()} "
                               f"{log.read_text() if log.is_file() else ''}")

    def sql(self, statement: str) -> None:
        """Run one statement as the superuser (outside a transaction: CREATE DATABASE needs that)."""
        import psycopg

        with psycopg.connect(host=str(self.folder), port=self.port, user=SUPERUSER, dbname="postgres",
                             autocommit=True) as conn:
            conn.execute(statement)

    def url(self, database: str) -> str:
        return f"postgresql+psycopg://{ROLE}@/{database}?host={self.folder}&port={self.port}"

    def new_database(self) -> str:
        """A new, empty database owned by ``ROLE``; its URL."""
        name = f"study_{os.getpid()}_{next(self.names)}"
        self.sql(f"CREATE DATABASE {name} OWNER {ROLE}")
        return self.url(name)

    def stop(self) -> None:
        if (self.folder / "data" / "postmaster.pid").is_file():
            subprocess.run([*self.as_user, str(self.bin / "pg_ctl"), "-D", str(self.folder / "data"), "-m",
                            "immediate", "-w", "stop"], check=False, capture_output=True, timeout=60)
        shutil.rmtree(self.folder, ignore_errors=True)
