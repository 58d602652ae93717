"""The ``colorgrid`` command line: one sub-command per job."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from colorgrid.cli_config import add_config_arguments, config_from_args
from colorgrid.config import AGENTS


def cmd_demo(args: argparse.Namespace) -> int:
    """Play one episode with random agents and draw it in the terminal."""
    from colorgrid.env import BatchEnv
    from colorgrid.render import render_ansi

    config = config_from_args(args)
    env = BatchEnv(config, num_envs=1, seed=args.seed)
    env.reset()
    rng = np.random.default_rng(args.seed)
    for _ in range(config.horizon):
        _, _, _, truncs, _ = env.step(rng.integers(0, config.num_actions, (1, config.num_agents)))
        if not args.quiet:
            print("\x1b[H\x1b[2J" + render_ansi(env.state, config), flush=True)
            time.sleep(1.0 / args.fps)
        if truncs.all():
            break
    scores = dict(zip(AGENTS, env.state.score[0].tolist()))
    print(f"episode over: {scores}")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    """Evaluate a leader with one follower, or several on the same seeds (--compare)."""
    import json
    from pathlib import Path

    from colorgrid.evaluate import evaluate, format_reports

    config = config_from_args(args)
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    followers = args.compare or [args.follower]
    reports = [evaluate(config, args.leader, name, args.episodes, args.seed, record_dir=args.record)
               for name in followers]
    print(format_reports(reports))
    if args.json:
        payload = reports[0] if len(reports) == 1 else {"reports": reports}
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(payload, indent=2))
        print(f"wrote {args.json}")
    return 0


def cmd_play(args: argparse.Namespace) -> int:
    """Run the play server (uvicorn) until interrupted."""
    from pathlib import Path

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


def cmd_view(args: argparse.Namespace) -> int:
    """Serve the 3D replay viewer (viser) for a folder of replays, or export one replay to standalone HTML."""
    from pathlib import Path

    from colorgrid.viewer import ReplayViewer, export_html

    path = Path(args.path)
    if args.export:
        if not path.is_file():
            raise FileNotFoundError(f"--export needs one replay file, got {path}")
        print(f"wrote {export_html(path, args.export)}")
        return 0
    folder = path if path.is_dir() else path.parent
    if not folder.is_dir():
        raise FileNotFoundError(f"{path} is neither a replay file nor a folder of replays")
    viewer = ReplayViewer(folder, host=args.host, port=args.port)
    print(f"ColorGrid 3D viewer: http://{args.host}:{viewer.port}/  ({len(viewer.replay_names())} replays "
          f"in {folder}; Ctrl+C stops)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        viewer.stop()
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="colorgrid", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="draw an episode of scripted agents in the terminal")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--fps", type=float, default=10.0)
    demo.add_argument("--quiet", action="store_true", help="print only the final score")
    add_config_arguments(demo)
    demo.set_defaults(func=cmd_demo)

    ev = sub.add_parser("eval", help="evaluate agents over a batch of episodes")
    ev.add_argument("--leader", default="astar", help="leader policy: a scripted name or a checkpoint .pt")
    ev.add_argument("--follower", default="bayes", help="follower policy: a scripted name or a checkpoint .pt")
    ev.add_argument("--compare", nargs="+", metavar="FOLLOWER", help="evaluate several followers on the same seeds")
    ev.add_argument("--episodes", type=int, default=100)
    ev.add_argument("--seed", type=int, default=0, help="episode i uses seed + i")
    ev.add_argument("--json", help="also write the report(s) as JSON to this path")
    ev.add_argument("--record", metavar="DIR", help="save every episode as a replay in DIR")
    add_config_arguments(ev)
    ev.set_defaults(func=cmd_eval)
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

    view = sub.add_parser("view", help="3D replay viewer (viser) for a folder of replays")
    view.add_argument("path", nargs="?", default="replays", help="a folder of *.replay.json (searched recursively) "
                      "or one replay file (its folder is listed)")
    view.add_argument("--host", default="127.0.0.1")
    view.add_argument("--port", type=int, default=8080, help="0 picks a free port")
    view.add_argument("--export", metavar="OUT.html", help="write PATH (one replay) as a standalone offline HTML file")
    view.set_defaults(func=cmd_view)

    from colorgrid.cli_replay import add_replay_commands

    add_replay_commands(sub)
    try:
        from train.cli import add_train_commands
    except ImportError:  # the trainer is not installed (e.g. a bare numpy install without train/)
        pass
    else:
        add_train_commands(sub)
    return parser


def command_name(args: argparse.Namespace) -> str:
    """The command as typed, for error lines: ``eval``, ``replay verify``, ``checkpoint export``."""
    words = [args.command]
    for sub_command in ("replay_command", "action"):  # the sub-commands' dests in cli_replay and train/cli
        if isinstance(getattr(args, sub_command, None), str):
            words.append(getattr(args, sub_command))
    return " ".join(words)


def main(argv: list[str] | None = None) -> int:
    """Run one command; a bad input ends it with one line, ``colorgrid COMMAND: error: ...``, and exit code 2."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, OSError) as err:  # FileNotFoundError is an OSError
        print(f"colorgrid {command_name(args)}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
