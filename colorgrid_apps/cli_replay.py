"""``colorgrid replay ...`` and ``colorgrid export``: checking, importing, releasing and exporting replays."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from colorgrid.presets import env_config
from colorgrid.replay.format import SUFFIX
from colorgrid.replay.paper_dumps import LAYOUTS
from colorgrid.resources import find_shipped, shipped, shipped_names
from colorgrid_apps.cli_env import add_config_arguments, config_changes


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
    """One dumped episode to a replay file, or a folder of the paper code's dumps to a folder with an index."""
    import shlex

    from colorgrid.replay import save
    from colorgrid.replay.frames import describe_frames
    from colorgrid.replay.index import INDEX_NAME
    from colorgrid.replay.paper_dumps import import_folder, import_trajectory, paper_dump

    changes = config_changes(args)
    config, fixed_density = env_config(args.preset, **changes), "block_density" in changes
    source, out = Path(args.trajectory), Path(args.out)
    if source.is_dir():
        if args.goal_info is not None or args.layout == "colorgrid":
            raise ValueError(f"{source} is a folder: its paper-code dumps are paired by name (give no GOAL_INFO "
                             f"and no --layout colorgrid)")
        if out.name.endswith(SUFFIX):
            raise ValueError(f"--out {out}: a folder for the replays and their {INDEX_NAME}, not one replay file")
        settings = [*(["--preset", args.preset] if args.preset != "default" else []),
                    *(["--config", str(args.config)] if args.config else []), *(f"--set={s}" for s in args.set)]
        command = shlex.join(["colorgrid", "replay", "import", str(source), "--out", str(out), *settings])
        written = import_folder(config, source, out, command, fixed_density)
        for path, replay in written:
            print(f"wrote {path} ({describe_frames(replay)})")
        print(f"wrote {out / INDEX_NAME}: {len(written)} replays of {source}")
        return 0
    if not out.name.endswith(SUFFIX):
        raise ValueError(f"--out {out}: a replay file ending in {SUFFIX} (a folder of dumps writes a folder)")
    dump = paper_dump(source)
    layout = args.layout or ("paper" if dump else "colorgrid")
    if args.goal_info is None and dump is None:
        raise ValueError(f"{source}: give its goal one-hots (GOAL_INFO) too; only a dump named as the paper's "
                         f"run_ppo.py names them (trajectory_iteration=I_env=E.npy) finds its own")
    goal_info = Path(args.goal_info) if args.goal_info is not None else dump.goal_info
    meta = {"iteration": dump.iteration, "env": dump.env} if dump else {}
    replay = import_trajectory(config, source, goal_info, layout, fixed_density, meta)
    save(replay, out)
    print(f"wrote {out} (frames replay of {layout} layout: {describe_frames(replay)})")
    return 0


def cmd_release(args: argparse.Namespace) -> int:
    from colorgrid_apps.release import RECIPE_SETTING, build_release, read_recipe_sweep, recipe_file

    recipe = read_recipe_sweep(Path(args.recipe)) if args.recipe else None  # a bad folder: refused before recording
    for line in recipe.skipped if recipe else ():
        print(line)
    entries = build_release(Path(args.out), episodes=args.episodes, gifs=Path(args.gifs) if args.gifs else None,
                            recipe=recipe)
    for trial in recipe.finished if recipe else ():
        print(f"recorded the arm '{trial.arm}' ({trial.folder.name}, step {trial.step:,}): "
              f"{Path(args.out) / recipe_file(trial.arm)}")
    arms = sum(entry.get("setting") == RECIPE_SETTING for entry in entries)
    print(f"wrote {len(entries)} replays ({arms} of the recipe ablation's arms) and {args.out}/index.json")
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

    from colorgrid.replay import load
    from colorgrid.replay.export import default_output, export

    files = _replay_files(Path(args.target))
    out = Path(args.out) if args.out else None
    if out is not None and len(files) > 1 and out.suffix:
        raise ValueError("--out must be a folder when exporting a folder of replays")
    bar = tqdm(files, unit="replay", disable=len(files) == 1)
    for path in bar:
        target = default_output(path, args.format)  # in the current folder
        if out is not None:
            target = out if len(files) == 1 and out.suffix else out / target.name
        written = export(load(path), target, args.format, fps=args.fps, cell=args.scale,
                         start=args.start, end=args.end, path=path)
    if len(files) == 1:
        print(f"wrote {written.resolve()}")
    else:
        print(f"wrote {len(files)} {args.format.upper()} files in {written.resolve().parent}")
    return 0


def cmd_branch(args: argparse.Namespace) -> int:
    from colorgrid.replay import load, save, verify
    from colorgrid.replay.branch import branch

    path = find_shipped(args.replay, "replays", SUFFIX)
    child = branch(load(path), args.step, args.follower, args.leader, args.seed, parent_name=path.name)
    tag = Path(args.follower).stem.replace(":", "_").replace("=", "").replace(",", "_")
    out = save(child, Path(args.out) / f"{path.name[:-len(SUFFIX)]}--branch{args.step}-{tag}{SUFFIX}")
    check = verify(child)
    print(f"wrote {out} ({child.num_steps} steps, the first {args.step} the parent's; {check.message}); final "
          f"team score {child.final()['team_score']:+g} (parent {load(path).final()['team_score']:+g})")
    return 0 if check.ok else 1


def cmd_rescore(args: argparse.Namespace) -> int:
    from colorgrid.replay.branch import format_rescore, rescore
    from colorgrid.replay.human_follower import format_human_report, human_follower_report

    files = _replay_files(Path(args.folder))
    try:
        report = rescore(files, args.follower, seed=args.seed)
    except ValueError as err:  # no 1:1 game: games of people in a follower seat of a team may still be measured
        report, nothing = None, err
    people = human_follower_report(files, args.follower, seed=args.seed, pickups=report)
    if report is None and people is None:
        raise nothing
    if report is not None:
        print(format_rescore(report))
    if people is not None:
        print(("\n" if report is not None else "") + format_human_report(people))
    if args.json:
        Path(args.json).write_text(json.dumps({**(report or {}), "human_follower": people}, indent=2))
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
    imp = rsub.add_parser(
        "import", help="import the paper code's trajectory dumps (a file, or a trajectories/<run> folder) or other "
                       "observation arrays as frames replays",
        description="Import observation frames as frames replays (docs/PAPER_CODE.md). A folder of the paper's "
                    "run_ppo.py dumps (trajectory_iteration=I_env=E.npy with goal_info_iteration=I_env=E.npy) is "
                    "paired by iteration and env and written to the --out folder as iterationI_envE.replay.json "
                    "with an index.json; one file is written to --out FILE.replay.json. The paper's planes, "
                    "[x, y] boards and color order are mapped (its blue stays blue); the block density is read from "
                    "the frames (17 blocks of each color: 0.05; 34: 0.10). Examples: colorgrid replay import "
                    "trajectories/run1 --out recordings/run1; colorgrid replay import "
                    "trajectory_iteration=0_env=0.npy --out ep.replay.json")
    imp.add_argument("trajectory", metavar="TRAJECTORY_OR_DIR",
                     help="a trajectories/<run> folder of the paper's dumps, or one .npy of frames [T+1, C+A, H, W] "
                          "(or [T+1, A, C+A, H, W]; A agents, 2 in 1:1)")
    imp.add_argument("goal_info", metavar="GOAL_INFO", nargs="?",
                     help="one file's .npy [T+1, C]: the leader's one-hot goal per frame (default for a dump named "
                          "trajectory_iteration=I_env=E.npy: the goal_info_iteration=I_env=E.npy beside it)")
    imp.add_argument("--out", required=True, help="the replay file to write (*.replay.json), or for a folder the "
                                                  "folder to write the replays and index.json into")
    imp.add_argument("--layout", choices=LAYOUTS,
                     help="how one file's planes are laid out: paper (run_ppo.py's: RED, BLUE, GREEN, [x, y]) or "
                          "colorgrid (this project's observations); default: paper for a file named as run_ppo.py "
                          "names its dumps, else colorgrid")
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
    rs = rsub.add_parser("rescore", help="replay every recorded leader's moves with each follower (open-loop); for "
                                         "games of a person in the follower seat, also their stated beliefs' "
                                         "accuracy, log-loss, Brier score and switch lags beside each follower's "
                                         "on the same history")
    rs.add_argument("folder", help="a folder of replays (e.g. the play server's recordings)")
    rs.add_argument("--follower", nargs="+", required=True, help="followers to compare; the first is the baseline")
    rs.add_argument("--seed", type=int, default=None, help="the followers' random seed (default: each episode's)")
    rs.add_argument("--json", help="also write the figures as JSON")
    rs.set_defaults(func=cmd_rescore)
    rel = rsub.add_parser("release", help="regenerate the released replay set")
    rel.add_argument("--out", default="replays")
    rel.add_argument("--episodes", type=int, default=2, help="episodes per (setting, follower)")
    rel.add_argument("--gifs", help="also export one GIF per setting into this folder (e.g. docs/images)")
    rel.add_argument("--recipe", metavar="SWEEP_DIR",
                     help="also record one replay per arm of the recipe ablation (docs/ASSISTANT_RECIPE.md) from "
                          "this sweep folder (e.g. runs/sweeps/assistant_recipe): each arm's seed-0 follower, trained "
                          "to its last step, beside the A* leader; an arm not finished is skipped. Without it the "
                          "recipe replays already released stay")
    rel.set_defaults(func=cmd_release)

    exp = sub.add_parser("export", help="export replays to GIF or MP4 without a display")
    exp.add_argument("target", help="a replay file or a folder of them, or a released replay's name (replay list)")
    exp.add_argument("--format", required=True, choices=["gif", "mp4"])
    exp.add_argument("--out", help="output file (one replay) or folder (default: the current folder, a file "
                                   "named after each replay)")
    exp.add_argument("--fps", type=float, default=8.0)
    exp.add_argument("--scale", type=int, default=12, help="pixels per grid cell (4..64)")
    exp.add_argument("--start", type=int, default=0, help="first step to draw")
    exp.add_argument("--end", type=int, default=None, help="last step to draw (default: the last)")
    exp.set_defaults(func=cmd_export)
