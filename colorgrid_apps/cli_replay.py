"""``colorgrid replay ...`` and ``colorgrid export``: checking, importing, releasing and exporting replays."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from colorgrid.replay.format import SUFFIX
from colorgrid.resources import find_shipped, shipped, shipped_names
from colorgrid_apps.cli_env import add_config_arguments, config_from_args


def _replay_files(target: Path) -> list[Path]:
    """A folder's replays, or the target itself: a path named like a replay is one, whatever it is. A target
    that is not a path here may name a released replay or folder (``default/astar+bayes_seed2026``)."""
    target = find_shipped(target, "replays", SUFFIX)
    if target.is_dir() and not target.name.endswith(SUFFIX):
        files = sorted(target.glob("*.replay.json"))
        if not files:
            raise ValueError(f"{target} holds no *.replay.json files")
        return files
    if not target.exists():
        raise FileNotFoundError(f"{target}: no such file or folder")
    return [target]


def team_entries(replay) -> list[dict]:
    """One entry per agent, in index order: ``name``, ``role``, ``symbol``, ``policy``, whether it logged
    ``beliefs``, and its totals (``score``, ``goal_pickups``, ``wrong_pickups``) when the replay has rewards."""
    cfg, final = replay.config, replay.final()
    out = []
    for name, role, symbol in zip(cfg.agent_names, cfg.roles, cfg.symbols):
        entry = {"name": name, "role": role, "symbol": symbol, "policy": replay.agents.get(name, {}).get("policy"),
                 "beliefs": replay.goal_probs.get(name) is not None}
        for total in ("score", "goal_pickups", "wrong_pickups"):
            if f"{name}_{total}" in final:
                entry[total] = final[f"{name}_{total}"]
        out.append(entry)
    return out


def agent_line(entry: dict) -> str:
    """``L1 leader_0 (leader, astar): +3 (4 goal, 1 wrong), beliefs``: one agent of ``team_entries``."""
    line = f"{entry['symbol']} {entry['name']} ({entry['role']}, {entry['policy'] or '?'})"
    if "score" in entry:
        line += f": {entry['score']:+g} ({entry['goal_pickups']} goal, {entry['wrong_pickups']} wrong)"
    return line + (", beliefs" if entry["beliefs"] else "")


def cmd_verify(args: argparse.Namespace) -> int:
    from colorgrid.replay import ReplayError, load, verify

    failures = 0
    for target in args.files:
        for path in _replay_files(Path(target)):
            replay = None
            try:
                replay = load(path)
                result = verify(replay, path)
                message = result.message
                failures += not result.ok
            except ReplayError as err:
                message, failures = f"error: {err.problem}", failures + 1
            print(f"{path}: {message}")
            if replay is not None and not replay.config.one_to_one:  # a team's agents are not implied by the id
                for entry in team_entries(replay):
                    print(f"  {agent_line(entry)}")
    return 1 if failures else 0


def cmd_info(args: argparse.Namespace) -> int:
    from colorgrid.replay import load

    replay = load(find_shipped(args.file, "replays", SUFFIX))
    print(json.dumps({"kind": replay.kind, "env_id": replay.env_id, "source": replay.source, "agents": replay.agents,
                      "team": team_entries(replay), "seed": replay.seed, "steps": replay.num_steps,
                      "ended": replay.ended, "final": replay.final(), "config": replay.config.to_dict(),
                      "meta": replay.meta}, indent=2))
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    import numpy as np

    from colorgrid.replay import import_frames, save

    config = config_from_args(args)
    try:
        planes, goal_info = np.load(args.trajectory), np.load(args.goal_info)
    except (OSError, ValueError) as err:
        raise ValueError(f"cannot read the .npy inputs: {err}") from None
    replay = import_frames(config, planes, goal_info, meta={"imported_from": Path(args.trajectory).name})
    out = save(replay, args.out)
    print(f"wrote {out} ({replay.num_steps} steps, frames replay)")
    return 0


def cmd_release(args: argparse.Namespace) -> int:
    from colorgrid_apps.release import build_release

    index = build_release(Path(args.out), episodes=args.episodes, gifs=Path(args.gifs) if args.gifs else None)
    print(f"wrote {len(index['replays'])} replays and {args.out}/index.json")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    """The released replays that ship with colorgrid, by the name the replay commands take."""
    names = shipped_names("replays", SUFFIX)
    for name in names:
        print(name)
    print(f"{len(names)} released replays in {shipped('replays')} (give a name to export, info, branch, verify)")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from colorgrid_apps.export import default_output, export
    from colorgrid.replay import load

    files = _replay_files(Path(args.target))
    out = Path(args.out) if args.out else None
    if out is not None and len(files) > 1 and out.suffix:
        raise ValueError("--out must be a folder when exporting a folder of replays")
    bar = tqdm(files, unit="replay", disable=len(files) == 1)
    for path in bar:
        target = default_output(path, args.format)
        if out is not None:
            target = out if len(files) == 1 and out.suffix else out / target.name
        written = export(load(path), target, args.format, fps=args.fps, cell=args.scale,
                         start=args.start, end=args.end, path=path)
        if len(files) == 1:
            print(f"wrote {written}")
    return 0


def cmd_branch(args: argparse.Namespace) -> int:
    from colorgrid.replay import load, save, verify
    from colorgrid_apps.branch import branch

    path = find_shipped(args.replay, "replays", SUFFIX)
    child = branch(load(path), args.step, args.follower, args.leader, args.seed, parent_name=path.name)
    tag = Path(args.follower).stem.replace(":", "_").replace("=", "").replace(",", "_")
    out = save(child, Path(args.out) / f"{path.name[:-len(SUFFIX)]}--branch{args.step}-{tag}{SUFFIX}")
    check = verify(child)
    print(f"wrote {out} ({child.num_steps} steps, the first {args.step} the parent's; {check.message}); final "
          f"team score {child.final()['team_score']:+g} (parent {load(path).final()['team_score']:+g})")
    return 0 if check.ok else 1


def cmd_rescore(args: argparse.Namespace) -> int:
    from colorgrid_apps.branch import format_rescore, rescore

    report = rescore(_replay_files(Path(args.folder)), args.follower, seed=args.seed)
    print(format_rescore(report))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))
        print(f"wrote {args.json}")
    return 0


def add_replay_commands(sub) -> None:
    replay = sub.add_parser("replay", help="check, inspect, import and release replays")
    rsub = replay.add_subparsers(dest="replay_command", required=True)
    verify = rsub.add_parser("verify", help="re-simulate replays and report the first step that differs, or ok "
                                            "(teams other than 1:1: then one line per agent)")
    verify.add_argument("files", nargs="+", help="replay files or folders")
    verify.set_defaults(func=cmd_verify)
    listing = rsub.add_parser("list", help="list the released replays that ship with colorgrid, by name")
    listing.set_defaults(func=cmd_list)
    info = rsub.add_parser("info", help="print a replay's header and totals, with one entry per agent (team)")
    info.add_argument("file")
    info.set_defaults(func=cmd_info)
    imp = rsub.add_parser("import", help="import a frames-only trajectory (observation planes + goal one-hots)")
    imp.add_argument("trajectory", help=".npy of shape [T+1, C+A, H, W] (or [T+1, A, C+A, H, W]); A agents, 2 in 1:1")
    imp.add_argument("goal_info", help=".npy of shape [T+1, C]: the leader's one-hot goal per frame")
    imp.add_argument("--out", required=True, help="replay file to write (*.replay.json)")
    add_config_arguments(imp)
    imp.set_defaults(func=cmd_import)
    br = rsub.add_parser("branch", help="continue a replay from step T with another follower (what-if)")
    br.add_argument("replay", help="the parent replay (an actions replay)")
    br.add_argument("--step", type=int, required=True, help="the first step the new follower acts in (0..T)")
    br.add_argument("--follower", required=True, help="the follower from step T: a policy name or checkpoint")
    br.add_argument("--leader", default="recorded", help="'recorded' (replay the leader's moves) or a policy")
    br.add_argument("--seed", type=int, default=None, help="the new agents' random seed (default: the episode's)")
    br.add_argument("--out", required=True, help="folder for the branch replay")
    br.set_defaults(func=cmd_branch)
    rs = rsub.add_parser("rescore", help="replay every recorded leader's moves with each follower (open-loop)")
    rs.add_argument("folder", help="a folder of replays (e.g. the play server's recordings)")
    rs.add_argument("--follower", nargs="+", required=True, help="followers to compare; the first is the baseline")
    rs.add_argument("--seed", type=int, default=None, help="the followers' random seed (default: each episode's)")
    rs.add_argument("--json", help="also write the figures as JSON")
    rs.set_defaults(func=cmd_rescore)
    rel = rsub.add_parser("release", help="regenerate the released replay set")
    rel.add_argument("--out", default="replays")
    rel.add_argument("--episodes", type=int, default=2, help="episodes per (setting, follower)")
    rel.add_argument("--gifs", help="also export one GIF per setting into this folder (e.g. docs/images)")
    rel.set_defaults(func=cmd_release)

    exp = sub.add_parser("export", help="export replays to GIF or MP4 without a display")
    exp.add_argument("target", help="a replay file or a folder of them, or a released replay's name (replay list)")
    exp.add_argument("--format", required=True, choices=["gif", "mp4"])
    exp.add_argument("--out", help="output file (one replay) or folder (default: beside each replay)")
    exp.add_argument("--fps", type=float, default=8.0)
    exp.add_argument("--scale", type=int, default=12, help="pixels per grid cell (4..64)")
    exp.add_argument("--start", type=int, default=0, help="first step to draw")
    exp.add_argument("--end", type=int, default=None, help="last step to draw (default: the last)")
    exp.set_defaults(func=cmd_export)
