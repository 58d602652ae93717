"""``colorgrid play``: the play server's command (registered through the ``colorgrid.commands`` entry point)."""

from __future__ import annotations

import argparse
import errno
import os
import socket
import threading
from pathlib import Path

from colorgrid.configkit import Flag, add_arguments, from_args
from server.settings import ServerSettings

FLAGS = {
    "show_belief": Flag(name="--hide-belief", invert=True, help="never show players the follower's belief"),
    "allowed_hosts": Flag(name="--allowed-host", extend_default=True),
    "allowed_origins": Flag(name="--allowed-origin", extend_default=True),
    "follower": Flag(help="default follower: ippo-shielded (the trained assistant for people, kept off blocks the "
                          "Bayesian one doubts), any follower name, a named spec or a checkpoint .pt"),
}
"""Where a flag differs from the one generated from its ``ServerSettings`` field."""


def add_play_command(sub) -> None:
    """``colorgrid play``: one flag per ``ServerSettings`` field, help from the field's docstring."""
    play = sub.add_parser("play", help="run the play server: lead in the browser, a follower assists")
    add_arguments(play, ServerSettings, FLAGS)
    play.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    add_cluster_arguments(play)
    play.set_defaults(func=cmd_play)


def cmd_play(args: argparse.Namespace) -> int:
    """Run the play server (uvicorn) until interrupted."""
    settings = from_args(ServerSettings, args, FLAGS)
    check_writable(settings.replays_dir, "--replays-dir")
    check_follower_names(settings.followers)
    check_follower(settings.follower)
    check_address_free(settings.host, settings.port)

    def announce(url: str) -> None:
        print(f"ColorGrid play server: {url}/  (replays in {settings.replays_dir}; Ctrl+C stops)", flush=True)

    return serve_or_launch(args, settings, settings.replays_dir, announce)


def add_cluster_arguments(parser: argparse.ArgumentParser) -> None:
    """``--processes``, ``--backends``, ``--cluster``: one process, or several behind HAProxy."""
    group = parser.add_argument_group("several processes behind HAProxy (docs/STUDIES.md, \"Running a large study\")")
    group.add_argument("--processes", type=int, default=1, metavar="N",
                       help="run N play-server processes on this machine behind HAProxy, which listens on --host "
                            "and --port (default 1: one process, no proxy)")
    group.add_argument("--backends", metavar="HOST:PORT,...",
                       help="run HAProxy alone on --host and --port, in front of these play servers (other machines "
                            "sharing the database and the recordings folder, each started with --cluster)")
    group.add_argument("--cluster", type=Path, metavar="FILE",
                       help="this server is one of the backends that FILE (cluster.json, written by --processes or "
                            "--backends) names: it answers as one of them, and /api/health reports them all")
    parser.add_argument("--stop-with-parent", action="store_true",
                        help="stop as Ctrl+C does (every process this command started included) when the program "
                             "that started it ends, even killed outright: for a bench, a test or a supervisor "
                             "script (not for a shell's `nohup ... &`, whose shell ends)")


def serve_or_launch(args: argparse.Namespace, settings: ServerSettings, folder: Path, announce,
                    plugin=None) -> int:
    """One play server (``--cluster``: one backend of several), or the launcher of several behind HAProxy
    (``--processes N``), or HAProxy alone (``--backends``); ``announce(url)`` prints where people connect;
    ``plugin``: the application served (a study), or None for free play."""
    from server.cluster.plan import check_processes
    from server.run import serve

    roles = [flag for flag, given in (("--processes", args.processes != 1), ("--backends", args.backends),
                                      ("--cluster", args.cluster)) if given]
    if len(roles) > 1:
        raise ValueError(f"{' and '.join(roles)} are one or the other: --processes N runs the backends and HAProxy "
                         "here, --backends HAProxy alone, --cluster one backend of those")
    check_processes(args.processes)
    if args.stop_with_parent:
        stop_with_parent()
    if args.processes > 1 or args.backends:
        from server.cluster.launcher import Cluster

        cluster = (Cluster.local(settings, args.processes, folder, plugin, args.log_level) if args.processes > 1
                   else Cluster.proxy_only(settings, args.backends, folder, plugin))
        if args.backends and plugin is not None and not str(plugin.database).startswith("postgresql"):
            print("warning: backends on other machines need one PostgreSQL database (--database "
                  "postgresql+psycopg://...): SQLite's locking is not safe over a network folder", flush=True)
        announce(cluster.url)
        where = f"{args.processes} processes" if args.processes > 1 else f"the backends {args.backends}"
        print(f"  HAProxy in front of {where}: {cluster.proxy_file} (backends listed in {cluster.plan_file})",
              flush=True)
        return cluster.run()
    member = None
    if args.cluster is not None:
        from server.cluster.plan import Membership

        member = Membership.of(args.cluster, settings.port)
    serve(settings, log_level=args.log_level, plugin=plugin, member=member, announce=announce)
    return 0


def check_address_free(host: str, port: int) -> None:
    """Refuse, before anything starts, an address where a server listens already (another study, say): whatever
    listens on ``--host`` and ``--port`` (one server, HAProxy in front of several) would otherwise share it with
    that one, and people would reach either at random. Port 0 (any free port) is always free."""
    if port == 0:
        return
    host = host.strip("[]")
    where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the servers bind: old connections may linger
        try:
            probe.bind((host, port))
        except OSError as err:
            if err.errno == errno.EADDRINUSE:
                raise ValueError(f"{where} is in use: another server listens there (another study?); stop it, or "
                                 "choose another --port") from None
            raise ValueError(f"cannot listen on {where} ({err.strerror or err}): choose another --host or --port") \
                from None


def stop_with_parent() -> None:
    """``--stop-with-parent``: this process stops as on SIGTERM once its parent is gone (at once if it is already:
    the parent is then init)."""
    from server.cluster.process import stop_with_parent as watch

    parent = os.getppid()
    threading.Thread(target=watch, args=(parent if parent != 1 else -1, 0.5,
                                         "colorgrid: the program that started this one is gone: stopping"),
                     daemon=True, name="parent-watch").start()


def check_writable(folder, flag: str) -> None:
    """Refuse to start a server that could not save what it records."""
    import tempfile

    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        raise ValueError(f"{flag} {folder} is not a writable folder ({err.strerror}); choose another") from None


def check_follower_names(names: tuple[str, ...]) -> None:
    """Refuse to start with a follower in the menu that is no policy name (``colorgrid play`` and ``study run``):
    each ``--followers`` gives one; names joined by a comma would be taken as one follower that no game could build
    (``copy,x.pt`` too, which reads as a checkpoint path, unless such a file exists)."""
    from colorgrid.policies import policy_names
    from colorgrid.policies.names import read_name

    for name in names:
        target = name.partition(":")[0]  # a comma among the parameters is a parameter's (bayes:lapse=0.2,rationality=3)
        joined = "," in target and not Path(target).is_file()
        if read_name(name) is None or joined:
            one_each = " (one name a flag: --followers copy --followers bayes)" if "," in name else ""
            raise ValueError(f"--followers {name!r} is no policy: give one of {policy_names()} or a checkpoint path "
                             f"ending in .pt{one_each}")


def check_follower(name: str) -> None:
    """Refuse to start with a default follower that cannot be loaded (every default game would fail)."""
    from colorgrid.policies import make_policy

    try:
        make_policy(name, role="follower")
    except (ValueError, FileNotFoundError, OSError) as err:
        raise ValueError(f"--follower {name!r} cannot be used: {err}") from None
