"""``colorgrid study run STUDY_FILE``, ``colorgrid study export STUDY_FILE --out DIR`` and ``colorgrid study power
STUDY_FILE --pilot DIR --measure M --difference D``."""

from __future__ import annotations

import argparse
import dataclasses
import os
import secrets
from pathlib import Path

from colorgrid.configkit import add_arguments, from_args
from colorgrid.resources import find_shipped
from server.cli import (FLAGS, add_cluster_arguments, check_address_free, check_follower_names, check_writable,
                        serve_or_launch)
from server.settings import ServerSettings
from server.study.config import Study, check_followers, load_study

ADMIN_TOKEN_ENV = "COLORGRID_ADMIN_TOKEN"
"""Set it to fix the admin token (a deployment); otherwise a new one is printed at every start."""


def study_folder(study: Study, replays_dir: Path | None) -> Path:
    """Where a study's replays and database live: ``recordings/<study id>`` unless given."""
    return replays_dir if replays_dir is not None else ServerSettings().replays_dir / study.id


def study_path(text: str) -> Path:
    """A study file's path, or the name of a shipped example study (``belief_display``)."""
    return find_shipped(text, "studies", ".toml")


def add_database_arguments(parser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--db", type=Path, metavar="PATH", help="the study's SQLite database (default: study.sqlite in "
                       "the replays folder)")
    where.add_argument("--database", metavar="URL", help="the study's database as a URL: "
                       "postgresql+psycopg://USER@HOST:PORT/DB (several servers share it) or sqlite:///PATH")


def study_database(args: argparse.Namespace, folder: Path) -> str | Path:
    """The database the flags name (a URL is checked here), else ``study.sqlite`` in the study's folder."""
    if args.database is not None:
        from server.study.store import database_url

        database_url(args.database)
        return args.database
    return args.db or folder / "study.sqlite"


def add_study_commands(sub) -> None:
    study = sub.add_parser("study", help="run a human study from a study file, and export its data")
    commands = study.add_subparsers(dest="study_command", required=True)
    run = commands.add_parser("run", help="serve the study: participants open /study?PROLIFIC_PID=..., the admin "
                              "/study/admin")
    run.add_argument("study_file", type=study_path, help="the study file (TOML; see docs/STUDIES.md), or the name of "
                     "a shipped example (belief_display)")
    add_database_arguments(run)
    add_arguments(run, ServerSettings, FLAGS, skip=("replays_dir",))
    run.add_argument("--replays-dir", type=Path, help="where the games are recorded (default: recordings/STUDY_ID)")
    run.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    add_cluster_arguments(run)
    run.set_defaults(func=cmd_run)
    export = commands.add_parser("export", help="write the study's tables (Parquet and CSV) for analysis")
    export.add_argument("study_file", type=study_path, help="the study file the study ran with (or its shipped name)")
    export.add_argument("--out", type=Path, required=True, help="the folder to write the tables to")
    export.add_argument("--replays-dir", type=Path, help="the study's replays folder (default: recordings/STUDY_ID)")
    add_database_arguments(export)
    export.set_defaults(func=cmd_export)
    power = commands.add_parser(
        "power", help="the participants an arm needs for a given power, from a pilot export's spread",
        description="How many participants an arm of the study needs to find a difference of --difference on "
                    "--measure between the levels of --factor, with the study's design (within participants: a paired "
                    "t-test on each participant's difference; between: a two-sample t-test), from the spread in a "
                    "pilot's export (the t-test's power, with scipy). Example: colorgrid study power "
                    "studies/human_follower.toml --pilot pilot_data --measure stated_accuracy --difference 0.05")
    power.add_argument("study_file", type=study_path, help="the study file (or its shipped name)")
    power.add_argument("--pilot", type=Path, required=True, metavar="EXPORT_DIR",
                       help="a pilot's export (the folder `colorgrid study export --out` wrote)")
    power.add_argument("--measure", required=True, help="a numeric column of the trials table (stated_accuracy, "
                                                        "probe_brier, follower_net_pickups, ...)")
    power.add_argument("--difference", type=float, required=True,
                       help="the smallest difference between the levels worth finding, in the measure's units")
    power.add_argument("--factor", help="the factor whose levels are compared (default: the study's first factor of "
                                        "two levels or more)")
    power.add_argument("--power", type=float, default=0.8, help="the power wanted (default 0.8)")
    power.add_argument("--alpha", type=float, default=0.05, help="the two-sided significance level (default 0.05)")
    power.add_argument("--keep-excluded", action="store_true",
                       help="plan on every counted trial, the excluded too (default: the trials and participants the "
                            "pilot's exclusions table excludes are left out, as the study's analysis leaves them)")
    power.add_argument("--json", type=Path, help="also write the figures as JSON")
    power.set_defaults(func=cmd_power)


def cmd_run(args: argparse.Namespace) -> int:
    study = load_study(args.study_file)
    folder = study_folder(study, args.replays_dir)
    settings = from_args(ServerSettings, args, FLAGS, skip=("replays_dir",), replays_dir=folder)
    check_follower_names(settings.followers)  # the flag's (the study file's are checked below, blamed on it)
    followers = tuple(dict.fromkeys((*settings.followers, *sorted(study.followers))))
    leaders = tuple(dict.fromkeys((*settings.leaders, *sorted(study.leaders))))  # the follower seat's AI leaders
    settings = dataclasses.replace(settings, followers=followers, leaders=leaders)
    check_writable(folder, "--replays-dir")
    check_followers(study, args.study_file)  # a follower named in the study file is blamed on its field there
    token = os.environ.get(ADMIN_TOKEN_ENV) or secrets.token_urlsafe(18)
    from server.study.plugin import StudySetup  # the study's extra (its database) is loaded only to run one

    setup = StudySetup(study, args.study_file.resolve(), study_database(args, folder), token)
    check_address_free(settings.host, settings.port)  # another study there: refused before its database is touched
    store = setup.store()  # a database of another study or schema stops here, in one line
    where = store.name
    store.close()

    def announce(base: str) -> None:
        print(f"ColorGrid study {study.id!r}: {len(study.conditions)} conditions, {study.design.assignment} subjects; "
              f"data in {where} and {folder}", flush=True)
        print(f"  participants: {base}/study?{study.id_params[0]}=PARTICIPANT_ID", flush=True)
        print(f"  admin:        {base}/study/admin   token: {token}  (never put it in a participant's link)",
              flush=True)

    return serve_or_launch(args, settings, folder, announce, setup)


def cmd_power(args: argparse.Namespace) -> int:
    import json

    from server.study.power import Comparison, format_power, pilot_trials, sample_size

    study = load_study(args.study_file)
    comparison = Comparison(args.measure, args.difference, args.factor, args.power, args.alpha)
    trials, left_out = pilot_trials(args.pilot, args.keep_excluded)
    report = {**sample_size(study, trials, comparison), "left_out": left_out}
    print(format_power(report), flush=True)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2, default=str))
        print(f"wrote {args.json}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from server.study.export import write_tables

    study = load_study(args.study_file)
    folder = study_folder(study, args.replays_dir)
    counts = write_tables(study, study_database(args, folder), folder, args.out)
    print(f"wrote {', '.join(f'{name} ({n} rows)' for name, n in counts.items())} to {args.out} "
          "as .parquet and .csv", flush=True)
    return 0
