"""``colorgrid sweep run | resume | report``: sweeps of training runs on Ray Tune (docs/SWEEPS.md)."""

from __future__ import annotations

import argparse

def add_sweep_commands(sub) -> None:
    sweep = sub.add_parser("sweep", help="run a sweep of training runs (configurations x seeds) on Ray Tune",
                           description="Sweeps on Ray Tune. A sweep file (sweeps/*.toml) names a preset, what varies "
                                       "and the seeds; each trial is an ordinary training run. Example: colorgrid "
                                       "sweep run sweeps/paper_table1_small.toml, then colorgrid sweep report "
                                       "runs/sweeps/paper_table1_small")
    sweep.add_argument("action", choices=["run", "resume", "report", "publish", "check", "baselines"],
                       help="run FILE | resume DIR | report DIR or FILE | publish DIR (keep its finished trials' "
                            "results in the file's results folder, and report them there) | check FILE (validate "
                            "and list the trials) | baselines FILE (evaluate the baselines its claims name on each "
                            "trial seed's evaluation episodes, into its results folder's baselines.json)")
    sweep.add_argument("path", help="run, check: a sweep file (.toml) or a shipped one's name (paper_table1_small); "
                                    "resume, publish: a sweep's folder; report: a sweep's folder, or a sweep file "
                                    "(the results kept in its results folder)")
    sweep.add_argument("--out", help="run: the sweep's folder (default: the file's 'out', runs/sweeps/<name>)")
    sweep.add_argument("--address", help="run, resume: join the Ray cluster at this address (e.g. 10.0.0.5:6379, "
                                          "or 'auto'); default: start a local Ray instance")
    sweep.add_argument("--local", type=int, metavar="N",
                       help="run: without Ray, N trials at a time as plain processes on this machine; the same "
                            "command again continues the trials from their checkpoints and skips finished ones")
    sweep.add_argument("--stop-after", type=float, metavar="SECONDS",
                       help="run --local: stop every trial with a checkpoint after this many seconds")
    sweep.add_argument("--num-cpus", type=int, help="run, resume: CPUs of the local Ray instance (default: all)")
    sweep.add_argument("--check", action="store_true",
                       help="baselines: compare with the kept baselines.json instead of writing it (exit 1 if a "
                            "figure differs)")
    sweep.set_defaults(func=cmd_sweep)


def cmd_sweep(args: argparse.Namespace) -> int:
    from train.sweep.spec import load_sweep

    if args.num_cpus is not None and args.num_cpus < 1:
        raise ValueError(f"--num-cpus must be >= 1, got {args.num_cpus}")
    if args.check and args.action != "baselines":
        raise ValueError("--check is for sweep baselines")
    if args.action == "check":
        spec = load_sweep(args.path, args.out)
        spec.check_files()
        print(f"{spec.path}: {spec.summary()}, metric {spec.metric} ({spec.mode}), into {spec.out}"
              + (f", {len(spec.claims)} claims" if spec.claims else "")
              + (f", results kept in {spec.results}" if spec.results else ""))
        return 0
    if args.action == "baselines":
        from train.sweep.baselines import write_baselines

        return write_baselines(load_sweep(args.path, args.out), check=args.check)
    if args.action == "report":
        from train.sweep.report import write_report

        text, _ = write_report(args.path)
        print(text)
        return 0
    if args.action == "publish":
        from train.sweep.report import publish_report

        where, count, _ = publish_report(args.path)
        files = ["trials.csv", "curves.csv"] + [f for f in ("report.md", "summary.csv", "claims.csv", "unfinished.csv")
                                                if (where / f).exists()]
        print(f"{count} finished trials kept in {where} ({', '.join(files)}); commit that folder")
        return 0
    if args.local is not None or args.stop_after is not None:
        if args.action != "run" or args.local is None:
            raise ValueError("--local N is for sweep run, and --stop-after goes with --local")
        from train.sweep.local import run_local

        return run_local(load_sweep(args.path, args.out), args.local, args.stop_after)
    from train.sweep.runner import resume_sweep, run_sweep

    if args.action == "run":
        return run_sweep(load_sweep(args.path, args.out), args.address, args.num_cpus)
    return resume_sweep(args.path, args.address, args.num_cpus)
