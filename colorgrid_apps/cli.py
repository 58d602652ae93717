"""The ``colorgrid`` command line: one sub-command per job."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from colorgrid.commandline import OneLineParser
from colorgrid.extras import MissingExtra, require
from colorgrid_apps.cli_env import add_config_arguments, config_from_args


def cmd_demo(args: argparse.Namespace) -> int:
    """Play one episode with random agents and draw it in the terminal."""
    from colorgrid.env import BatchEnv
    from colorgrid.render import render_ansi

    config = config_from_args(args)
    env = BatchEnv(config, num_envs=1, seed=args.seed, autoreset=False)  # the scores stay after the last step
    env.reset()
    rng = np.random.default_rng(args.seed)
    for _ in range(config.horizon):
        _, _, _, truncs, _ = env.step(rng.integers(0, config.num_actions, (1, config.num_agents)))
        if not args.quiet:
            print("\x1b[H\x1b[2J" + render_ansi(env.state, config), flush=True)
            time.sleep(1.0 / args.fps)
        if truncs.all():
            break
    scores = dict(zip(config.agent_names, env.state.score[0].tolist()))
    print(f"episode over: {scores}")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    """Evaluate a team (a leader with one follower by default), or several followers on the same seeds (--compare)."""
    import json
    from pathlib import Path

    from colorgrid.evaluate import evaluate, format_reports

    config = team_config(config_from_args(args), args.team)
    agents = agent_policies(args.agent, config)
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    followers = args.compare or [args.follower]
    if args.address and not args.leaders:
        raise ValueError("--address runs the cells of a --leaders matrix on Ray; add --leaders POPULATION")
    if args.leaders:
        from colorgrid_apps.matrix import evaluate_matrix, format_matrix, leaders_from

        if args.record:
            raise ValueError("--record records one leader's episodes; use --leader with it, not --leaders")
        if not config.one_to_one or agents:
            raise ValueError("--leaders pairs one leader of a population with one follower (a 1:1 team); "
                             "leave out --team and --agent")
        payload = evaluate_matrix(config, leaders_from(args.leaders), followers, args.episodes, args.seed,
                                  workers=args.workers, address=args.address)
        print(format_matrix(payload))
    else:
        reports = [evaluate(config, args.leader, name, args.episodes, args.seed, record_dir=args.record, agents=agents)
                   for name in followers]
        print(format_reports(reports))
        payload = reports[0] if len(reports) == 1 else {"reports": reports}
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(payload, indent=2))
        print(f"wrote {args.json}")
    return 0


def team_shape(text: str) -> tuple[int, int]:
    """``"2:1"`` -> ``(2, 1)``: the ``--team`` argument, leaders then followers (1..8 each)."""
    from colorgrid.config import MAX_PER_ROLE

    leaders, sep, followers = text.partition(":")
    if not (sep and leaders.isdigit() and followers.isdigit()
            and 1 <= int(leaders) <= MAX_PER_ROLE and 1 <= int(followers) <= MAX_PER_ROLE):
        raise argparse.ArgumentTypeError(f"expected LEADERS:FOLLOWERS with 1..{MAX_PER_ROLE} of each, e.g. 2:1; "
                                         f"got {text!r}")
    return int(leaders), int(followers)


def team_config(config, team: tuple[int, int] | None):
    """``config`` with the ``--team`` shape; an error if the config (``--config``/``--set``) names another team."""
    if team is None:
        return config
    named = (config.num_leaders, config.num_followers)
    if not config.one_to_one and named != team:
        raise ValueError(f"--team {team[0]}:{team[1]} disagrees with the config's team {named[0]}:{named[1]} "
                         "(num_leaders, num_followers); give one of them")
    return config.replace(num_leaders=team[0], num_followers=team[1])


def agent_policies(items: list[str], config) -> dict[str, str]:
    """``["leader_1=person:slip=0.1"]`` -> ``{"leader_1": "person:slip=0.1"}``, names checked against the team."""
    agents: dict[str, str] = {}
    for item in items:
        name, sep, policy = item.partition("=")
        if not sep or not name or not policy:
            raise ValueError(f"--agent expects NAME=POLICY, e.g. leader_1=person:slip=0.1; got {item!r}")
        if name in agents:
            raise ValueError(f"--agent names {name!r} twice")
        try:
            config.index(name)
        except ValueError as err:
            raise ValueError(f"--agent {item}: {err}") from None
        agents[name] = policy
    return agents


def cmd_view(args: argparse.Namespace) -> int:
    """Serve the 3D replay viewer (viser) for a folder of replays, or export one replay to standalone HTML."""
    from pathlib import Path

    from colorgrid.replay.format import SUFFIX
    from colorgrid.resources import find_shipped, shipped

    require("viewer", "colorgrid view")
    from colorgrid_apps.viewer import ReplayViewer
    from colorgrid_apps.viewer_export import export_html

    path = shipped("replays") if args.path is None else find_shipped(args.path, "replays", SUFFIX)
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
    from colorgrid import __version__

    parser = OneLineParser(prog="colorgrid", description="The colorgrid command line: one sub-command per job.")
    parser.add_argument("--version", action="version", version=f"colorgrid {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    demo = sub.add_parser("demo", help="draw an episode of random agents in the terminal")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--fps", type=float, default=10.0)
    demo.add_argument("--quiet", action="store_true", help="print only the final score")
    add_config_arguments(demo)
    demo.set_defaults(func=cmd_demo)

    ev = sub.add_parser("eval", help="evaluate agents over a batch of episodes")
    ev.add_argument("--leader", default="astar", help="every leader's policy: a scripted name (person:slip=0.1,... "
                    "with parameters), a population or a checkpoint .pt")
    ev.add_argument("--follower", default="bayes", help="every follower's policy: a scripted name or a checkpoint .pt")
    ev.add_argument("--compare", nargs="+", metavar="FOLLOWER", help="evaluate several followers on the same seeds")
    ev.add_argument("--team", type=team_shape, metavar="LEADERS:FOLLOWERS", help="team shape, e.g. 2:1 (1..8 of "
                    "each; the same as --set env.num_leaders=2 --set env.num_followers=1): tables per agent and per "
                    "role")
    ev.add_argument("--agent", action="append", default=[], metavar="NAME=POLICY", help="one agent's policy in "
                    "place of its role's, e.g. --agent leader_1=person:slip=0.1 (repeatable; names: leader_0.., "
                    "follower_0.., or leader/follower in a 1:1 team)")
    ev.add_argument("--leaders", metavar="POPULATION", help="a leader x follower matrix over a population "
                    "(population:people, population:people#held_out, or FILE.json[#PART]) with paired differences "
                    "against the first follower")
    ev.add_argument("--episodes", type=int, default=100)
    ev.add_argument("--workers", type=int, default=None, help="with --leaders: processes for the cells (default: "
                    "one per CPU; the result is the same for any number)")
    ev.add_argument("--address", help="with --leaders: run the cells as Ray tasks on the Ray cluster at this "
                    "address (HEAD:6379, or 'auto'; needs the sweep extra); the result is the same")
    ev.add_argument("--seed", type=int, default=0, help="episode i uses seed + i")
    ev.add_argument("--json", help="also write the report(s) as JSON to this path")
    ev.add_argument("--record", metavar="DIR", help="save every episode as a replay in DIR")
    add_config_arguments(ev)
    ev.set_defaults(func=cmd_eval)
    view = sub.add_parser("view", help="3D replay viewer (viser) for a folder of replays")
    view.add_argument("path", nargs="?", help="a folder of *.replay.json (searched recursively), one replay file (its "
                      "folder is listed) or a released replay's name (default: the released replays)")
    view.add_argument("--host", default="127.0.0.1")
    view.add_argument("--port", type=int, default=8080, help="0 picks a free port")
    view.add_argument("--export", metavar="OUT.html", help="write PATH (one replay) as a standalone offline HTML file "
                      "(board, step/score/goal panel and belief chart; its slider counts steps)")
    view.set_defaults(func=cmd_view)

    from colorgrid_apps.cli_replay import add_replay_commands

    add_replay_commands(sub)
    for add_commands in plugin_commands():
        add_commands(sub)
    return parser


def missing_extra_commands(extra: str, names: tuple[str, ...]):
    """``add(subparsers)`` for commands whose extra is not installed: each takes anything and says in one line
    which extra to install (``OneLineParser.needs``)."""
    def add(sub):
        for name in names:
            sub.add_parser(name, help=f"(needs pip install 'colorgrid[{extra}]')", add_help=False, needs=extra)
    return add


def plugin_commands() -> list:
    """``add(subparsers)`` functions of the applications that declare their commands under the
    ``colorgrid.commands`` entry points (each a ``colorgrid.extras.Commands``: the play server, the trainer, ...),
    in entry-point name order. Commands whose extra is not installed are added in their place by
    ``missing_extra_commands``; those of a package that cannot be imported are left out."""
    from importlib.metadata import entry_points

    from colorgrid.extras import Commands, missing

    found = []
    for point in sorted(entry_points(group="colorgrid.commands"), key=lambda p: p.name):
        try:
            commands = point.load()
        except ImportError:  # that application is not installed here
            continue
        except AttributeError:  # the installed metadata names what this code no longer has
            commands = None
        if not isinstance(commands, Commands):
            print(f"colorgrid: error: the installed entry point colorgrid.commands {point.name} = {point.value} does "
                  "not match this code; install colorgrid again (in a checkout: pip install -e .)", file=sys.stderr)
            sys.exit(2)
        try:
            found.append(missing_extra_commands(commands.extra, commands.names) if missing(commands.extra)
                         else commands.load())
        except ImportError:
            continue
    return found


def main(argv: list[str] | None = None) -> int:
    """Run one command; a bad input ends it with one line, ``colorgrid COMMAND: error: ...``, and exit code 2."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, OSError, MissingExtra) as err:  # FileNotFoundError is an OSError
        print(f"colorgrid {' '.join(args.command_words)}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
