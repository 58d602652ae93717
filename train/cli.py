"""``colorgrid train`` (also ``python -m train``) and ``colorgrid checkpoint``: run, resume, inspect, export."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

from colorgrid.commandline import OneLineParser
from colorgrid.config import ROLES
from colorgrid.enums import Role
from colorgrid.extras import MissingExtra
from colorgrid.files import JSONFileError, read_json_object
from train.config import TrainConfig, load_preset, preset_names, resolve


def add_train_commands(sub) -> None:
    train = sub.add_parser("train", help="train agents with IPPO (presets in train/presets/)",
                           description="Train with IPPO. Settings: a preset, then a JSON config file, then --set "
                                       "overrides, each on top of the last. Example: colorgrid train --preset "
                                       "follower_astar --set total_steps=2000000 --out runs/follower")
    train.add_argument("--preset", default="default", help=f"one of {preset_names()} or a JSON file")
    train.add_argument("--config", help="a JSON file of settings applied on top of the preset")
    train.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       help="override one setting, e.g. ppo.lr=3e-4, follower.net.lstm=true, env.asymmetric=false "
                            "(env settings are env.KEY here, in sweep files, and on eval, demo and replay import)")
    train.add_argument("--out", help="run directory (default runs/<preset>-<time>)")
    train.add_argument("--seeds", metavar="SEEDS",
                       help="train one run per seed as one pack in one process (train/pack.py), each in OUT/seed_N: "
                            "a range 0-7, a list 0,3,5, or both 0-3,8 (replaces the config's seed)")
    train.add_argument("--resume", metavar="RUN_DIR", help="continue a run from RUN_DIR/checkpoints/latest.pt (a "
                                                           "--seeds run: from each RUN_DIR/seed_N, as one pack)")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.add_argument("--no-tensorboard", action="store_true", help="no TensorBoard event files")
    train.add_argument("--print-config", action="store_true", help="print the resolved config and exit")
    train.set_defaults(func=cmd_train)

    ck = sub.add_parser("checkpoint", help="inspect a checkpoint, export one agent as a small policy file, or import "
                                           "one from the paper's code",
                        description="info, export, card: a checkpoint .pt of this trainer. import-paper: a state "
                                    "dict saved by the paper's run_ppo.py (leader_iteration=N.pth, "
                                    "follower_iteration=N.pth) to a checkpoint every command takes, with a model card "
                                    "beside it. Example: colorgrid checkpoint import-paper follower_iteration=100.pth "
                                    "--role follower --asymmetric --out paper_follower.pt")
    ck.add_argument("action", choices=["info", "export", "card", "import-paper"])
    ck.add_argument("path", help="a checkpoint .pt (import-paper: the paper's .pth)")
    ck.add_argument("--agent", help="export, card: which network: leader or follower (1:1 team), an agent's name "
                                    "(leader_1, follower_0) or the role whose agents share one network")
    ck.add_argument("--out", help="export: destination .pt; card: destination .md (a .json of the reports beside it)")
    ck.add_argument("--run", help="card: the run directory (for the wall time)")
    ck.add_argument("--temperature", type=float,
                    help="export: how the network acts wherever the file is loaded without a temperature of its "
                         "own (1 samples as trained, 0 is greedy; default: the source's)")
    ck.add_argument("--min-belief", type=float,
                    help="export: the least belief in a block's color at which the network may step onto it, "
                         "wherever the file is loaded without one of its own (0: every move; default: the source's)")
    ck.add_argument("--role", choices=ROLES, help="import-paper: the role the paper's network played")
    side = ck.add_mutually_exclusive_group()
    side.add_argument("--asymmetric", dest="asymmetric", action="store_true", default=None,
                      help="import-paper: it was trained with the goal hidden from the follower (needed for a follower)")
    side.add_argument("--symmetric", dest="asymmetric", action="store_false",
                      help="import-paper: it was trained with the goal shown to both (the default for a leader)")
    ck.add_argument("--command", dest="train_command", default="",  # not "command": that names the sub-command
                    help="card: the command that trained it")
    ck.set_defaults(func=cmd_checkpoint)

    bc = sub.add_parser("train-bc", help="learn a leader from recorded games (behaviour cloning)",
                        description="Behaviour cloning: re-simulate every actions replay (*.replay.json, searched "
                                    "recursively) in the folders and train the leader's network to take the "
                                    "recorded leader's actions. Episodes are split into training and held-out "
                                    "sets; the result loads wherever a policy name does (--leader OUT). Example: "
                                    "colorgrid train-bc replays/ --out leader_bc.pt --epochs 20")
    bc.add_argument("recordings", nargs="+", metavar="RECORDINGS_DIR", help="folders of recorded games")
    bc.add_argument("--out", default="leader_bc.pt", help="the checkpoint to write (default: %(default)s)")
    bc.add_argument("--epochs", type=int, help="passes over the training episodes (default 15)")
    bc.add_argument("--seed", type=int, help="seeds the split, the initial weights and the batch order (default 0)")
    bc.add_argument("--holdout", type=float, help="fraction of episodes held out to measure accuracy (default 0.2)")
    bc.add_argument("--net-hidden", type=int, help="width of the network's trunk (net.hidden, default 128)")
    bc.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a setting of train/bc.py's BCConfig, e.g. lr=1e-3, batch_size=128, net.lstm=true")
    bc.set_defaults(func=cmd_train_bc)


def resolve_config(args: argparse.Namespace) -> TrainConfig:
    """The run's config: the preset, then the ``--config`` file, then the ``--set`` overrides (``train.config.resolve``)."""
    file = {}
    if args.config:
        try:
            file = read_json_object(args.config, "a JSON object of training settings (as in a preset)")
        except JSONFileError as err:
            raise ValueError(f"--config {err}") from None
    return resolve(load_preset(args.preset), file, overrides=args.set)


def resumed_config(run_dir: Path, overrides: list[str]) -> TrainConfig:
    """The config a run was started with (``RUN_DIR/config.json``), with ``--set`` overrides on top."""
    saved = run_dir / "config.json"
    if not saved.exists():
        raise FileNotFoundError(f"--resume {run_dir}: no config.json there; is it a run directory?")
    data = read_json_object(saved, "a JSON object of training settings (the run's config)")
    try:
        return resolve(data, overrides=overrides)
    except ValueError as err:
        raise ValueError(f"{saved}{' with the --set overrides' if overrides else ''}: {err}") from None


MAX_SEEDS = 4096
"""The most seeds ``--seeds`` trains as one pack (as a sweep's ``[resources] pack``)."""


def parse_seeds(text: str) -> list[int]:
    """``--seeds``: ``0-7``, ``0,3,5`` or ``0-3,8`` as a sorted list of distinct seeds."""
    seeds = set()
    for part in text.split(","):
        low, dash, high = part.strip().partition("-")
        try:
            first, last = int(low), int(high if dash else low)
        except ValueError:
            first, last = 0, -1
        if not 0 <= first <= last or last - first >= MAX_SEEDS:
            raise ValueError(f"--seeds {text!r}: give seeds as a range 0-7, a list 0,3,5, or both 0-3,8 (whole "
                             f"numbers >= 0, each range low-high with low <= high)")
        seeds.update(range(first, last + 1))
    if len(seeds) > MAX_SEEDS:
        raise ValueError(f"--seeds {text!r} names {len(seeds)} seeds; a pack trains at most {MAX_SEEDS}")
    return sorted(seeds)


def seed_runs(run_dir: Path) -> list[Path]:
    """The runs of a ``--seeds`` run directory, ``RUN_DIR/seed_N`` by seed (none: it is one run)."""
    runs = [d for d in run_dir.glob("seed_*") if d.is_dir() and d.name[5:].isdigit()]
    return sorted(runs, key=lambda d: int(d.name[5:]))


def cmd_train(args: argparse.Namespace) -> int:
    if args.resume:
        run_dir = Path(args.resume)
        if args.seeds is not None:
            raise ValueError("--seeds starts runs; --resume continues them with the seeds they were started with: "
                             "give one or the other")
        runs = seed_runs(run_dir) or [run_dir]
        configs = [resumed_config(run, args.set) for run in runs]
    else:
        config = resolve_config(args)
        run_dir = Path(args.out or f"runs/{Path(args.preset).stem}-{time.strftime('%Y%m%d-%H%M%S')}")
        if args.seeds is not None:
            seeds = parse_seeds(args.seeds)
            configs = [resolve(config.to_dict(), overrides=[f"seed={seed}"]) for seed in seeds]
            runs = [run_dir / f"seed_{seed}" for seed in seeds]
        else:
            configs, runs = [config], [run_dir]
    if args.print_config:
        print(json.dumps(configs[0].to_dict() if len(configs) == 1 else [c.to_dict() for c in configs], indent=2))
        return 0
    from train.pack import Pack  # torch: imported once the config is known to be good
    from train.packing import check_packable
    from train.trainer import Trainer

    check_packable(configs)
    trainers = [Trainer(config, run, progress=not args.no_progress, tensorboard=not args.no_tensorboard)
                for config, run in zip(configs, runs)]
    if args.resume:
        for trainer, run in zip(trainers, runs):
            trainer.restore(run / "checkpoints" / "latest.pt")
        print(f"resuming {run_dir} at step {', '.join(str(t.step) for t in trainers)}")
    pack = f" as one pack of {len(trainers)} (seeds {', '.join(str(c.seed) for c in configs)})" if len(runs) > 1 else ""
    print(f"training {configs[0].num_iterations} iterations of {configs[0].batch_steps} steps on "
          f"{trainers[0].device}{pack}; run directory {run_dir}")
    interrupted = threading.Event()

    def on_ctrl_c(signum, frame):
        if interrupted.is_set():
            raise KeyboardInterrupt  # the second Ctrl+C: at once (the last checkpoint stays)
        interrupted.set()
        print("\nstopping after this iteration, with a checkpoint; Ctrl+C again to stop at once", file=sys.stderr,
              flush=True)

    previous = signal.signal(signal.SIGINT, on_ctrl_c)
    try:
        lasts = Pack(trainers).train(stop=interrupted.is_set)
    except KeyboardInterrupt:
        print(f"stopped at once; continue from the last checkpoint with: colorgrid train --resume {run_dir}",
              file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGINT, previous)
    if interrupted.is_set() and not all(t.finished for t in trainers):
        print(f"stopped at step {trainers[0].step} of {configs[0].end_step}; continue with: "
              f"colorgrid train --resume {run_dir}")
        return 130
    for trainer, last in zip(trainers, lasts):
        shown = {k: round(v, 3) for k, v in last.items() if isinstance(v, float) and ("eval/" in k or k == "sps")}
        seed = f" (seed {trainer.config.seed})" if len(trainers) > 1 else ""
        print(f"done at step {trainer.step}{seed}: {shown}")
        print(f"checkpoints in {trainer.run_dir / 'checkpoints'}")
    return 0


def cmd_checkpoint(args: argparse.Namespace) -> int:
    from train.acting import ACTING
    from train.checkpoint import export_agent, load_checkpoint

    if args.action == "import-paper":
        return cmd_import_paper(args)
    if args.action == "info":
        ckpt = load_checkpoint(args.path)
        agents = {k: (v["net"] if v else None) for k, v in ckpt["agents"].items()}
        acting = {name: {k: v.get(name, default) for k, v in ckpt["agents"].items() if v}
                  for name, (_, default) in ACTING.items()}
        print(json.dumps({"step": ckpt["step"], "iteration": ckpt.get("iteration"), "agents": agents, **acting,
                          "env_config": ckpt["env_config"], "resumable": ckpt.get("trainer_state") is not None},
                         indent=2))
        return 0
    if not args.agent or not args.out:
        raise ValueError("needs --agent (leader, follower, or an agent's name such as follower_1) and --out PATH")
    if args.action == "card":
        from train.card import write_card

        print(f"wrote {write_card(args.path, args.agent, args.run, args.train_command, args.out)}")
        return 0
    path = export_agent(args.path, args.agent, args.out, args.temperature, args.min_belief)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0


def cmd_import_paper(args: argparse.Namespace) -> int:
    from train.paper_code import import_paper_checkpoint

    if not args.role or not args.out:
        raise ValueError("needs --role leader|follower (the role the paper's network played) and --out PATH.pt")
    if args.asymmetric is None and args.role == Role.FOLLOWER:
        raise ValueError("say how the follower was trained: --asymmetric (it never saw the goal) or --symmetric")
    path = import_paper_checkpoint(args.path, args.role, args.out, asymmetric=bool(args.asymmetric))
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB) and its model card {path.with_suffix('.md')}")
    return 0


def cmd_train_bc(args: argparse.Namespace) -> int:
    from train.bc import bc_config, train_bc  # torch: imported only for this command

    flags = {"epochs": args.epochs, "seed": args.seed, "holdout": args.holdout}
    changes = {name: value for name, value in flags.items() if value is not None}
    if args.net_hidden is not None:
        changes["net"] = {"hidden": args.net_hidden}
    train_bc(args.recordings, args.out, bc_config(changes, args.set))
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m train ARGS`` is ``colorgrid train ARGS``, on this package's own parser; a bad input ends it with
    one line, ``colorgrid train: error: ...``, and exit code 2, as the ``colorgrid`` command ends it."""
    parser = OneLineParser(prog="colorgrid")  # its sub-command "train" completes the name in error lines
    add_train_commands(parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser))
    args = parser.parse_args(["train", *(sys.argv[1:] if argv is None else argv)])
    try:
        return int(args.func(args) or 0)
    except (ValueError, OSError, MissingExtra) as err:  # FileNotFoundError is an OSError
        print(f"colorgrid train: error: {err}", file=sys.stderr)
        return 2
