"""``colorgrid play``: the play server's command (registered through the ``colorgrid.commands`` entry point)."""

from __future__ import annotations

import argparse

from colorgrid.configkit import Flag, add_arguments, from_args
from server.settings import ServerSettings


FLAGS = {
    "show_belief": Flag(name="--hide-belief", invert=True, help="never show players the follower's belief"),
    "allowed_hosts": Flag(name="--allowed-host", extend_default=True),
    "allowed_origins": Flag(name="--allowed-origin", extend_default=True),
    "follower": Flag(help="default follower: bayes-people (the people-robust Bayesian one), any follower name, a named spec or a checkpoint .pt"),
}
"""Where a flag differs from the one generated from its ``ServerSettings`` field."""


def add_play_command(sub) -> None:
    """``colorgrid play``: one flag per ``ServerSettings`` field, help from the field's docstring."""
    play = sub.add_parser("play", help="run the play server: lead in the browser, a follower assists")
    add_arguments(play, ServerSettings, FLAGS)
    play.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    play.set_defaults(func=cmd_play)


def cmd_play(args: argparse.Namespace) -> int:
    """Run the play server (uvicorn) until interrupted."""
    from server.run import serve

    settings = from_args(ServerSettings, args, FLAGS)
    check_writable(settings.replays_dir, "--replays-dir")
    check_follower(settings.follower)
    print(f"ColorGrid play server: http://{settings.host}:{settings.port}/  (replays in {settings.replays_dir}; "
          "Ctrl+C stops)", flush=True)
    serve(settings, log_level=args.log_level)
    return 0


def check_writable(folder, flag: str) -> None:
    """Refuse to start a server that could not save what it records."""
    import tempfile

    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        raise ValueError(f"{flag} {folder} is not a writable folder ({err.strerror}); choose another") from None


def check_follower(name: str) -> None:
    """Refuse to start with a default follower that cannot be loaded (every default game would fail)."""
    from colorgrid.policies import make_policy

    try:
        make_policy(name, role="follower")
    except (ValueError, FileNotFoundError, OSError) as err:
        raise ValueError(f"--follower {name!r} cannot be used: {err}") from None
