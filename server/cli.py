"""``colorgrid play``: the play server's command (registered through the ``colorgrid.commands`` entry point)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_play_command(sub) -> None:
    play = sub.add_parser("play", help="run the play server: lead in the browser, a follower assists")
    play.add_argument("--host", default="127.0.0.1")
    play.add_argument("--port", type=int, default=8000)
    play.add_argument("--follower", default="ippo", help="default follower: ippo (the shipped trained one), a "
                      "scripted name or a checkpoint .pt")
    play.add_argument("--preset", default="default", help="default environment preset")
    play.add_argument("--tick-hz", type=float, default=5.0, help="real-time mode: steps per second")
    play.add_argument("--replays-dir", default="recordings", help="where every game is saved")
    play.add_argument("--max-sessions", type=int, default=100, help="concurrent games")
    play.add_argument("--hide-belief", action="store_true", help="never show players the follower's belief")
    play.add_argument("--rejoin-grace-s", type=float, default=30.0, help="how long a dropped game waits for its player")
    play.add_argument("--idle-timeout-s", type=float, default=300.0, help="close and save games idle this long")
    play.add_argument("--inference-deadline-ms", type=float, default=100.0, help="follower budget per step")
    play.add_argument("--allowed-host", action="append", default=[], metavar="HOST",
                      help="also answer requests for this Host (a deployment's name; repeatable; '*' for any)")
    play.add_argument("--allowed-origin", action="append", default=[], metavar="ORIGIN",
                      help="also let pages from this origin (https://study.example.org) play; repeatable")
    play.add_argument("--max-connections", type=int, default=400, help="open play WebSockets")
    play.add_argument("--new-games-per-minute", type=float, default=30.0, help="games one address may start a minute")
    play.add_argument("--max-replay-mb", type=float, default=50.0, help="larger replay files are never loaded")
    play.add_argument("--max-exports", type=int, default=2, help="GIF/MP4 exports made at once (then 503, retry)")
    play.add_argument("--max-messages-per-s", type=float, default=40.0,
                      help="messages a socket may send per second (bursts of twice that)")
    play.add_argument("--connection-idle-s", type=float, default=60.0,
                      help="close a socket with no game that sends nothing this long")
    play.add_argument("--header-timeout-s", type=float, default=10.0,
                      help="close an HTTP request whose headers take longer than this")
    play.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    play.set_defaults(func=cmd_play)


def cmd_play(args: argparse.Namespace) -> int:
    """Run the play server (uvicorn) until interrupted."""
    from server.run import serve
    from server.settings import ServerSettings

    settings = ServerSettings(host=args.host, port=args.port, follower=args.follower, preset=args.preset,
                              tick_hz=args.tick_hz, replays_dir=Path(args.replays_dir), max_sessions=args.max_sessions,
                              show_belief=not args.hide_belief, rejoin_grace_s=args.rejoin_grace_s,
                              idle_timeout_s=args.idle_timeout_s, inference_deadline_ms=args.inference_deadline_ms,
                              allowed_hosts=(*ServerSettings.allowed_hosts, *args.allowed_host),
                              allowed_origins=tuple(args.allowed_origin), max_connections=args.max_connections,
                              new_games_per_minute=args.new_games_per_minute, max_replay_mb=args.max_replay_mb,
                              max_exports=args.max_exports, max_messages_per_s=args.max_messages_per_s,
                              connection_idle_s=args.connection_idle_s, header_timeout_s=args.header_timeout_s)
    check_writable(settings.replays_dir, "--replays-dir")
    check_follower(settings.follower)
    print(f"ColorGrid play server: http://{args.host}:{args.port}/  (replays in {args.replays_dir}; Ctrl+C stops)",
          flush=True)
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
