"""When each claim was declared, against the data: the record ``claims_declared.csv`` that ``sweep run`` writes
before its first trial starts, and the reading the report makes of it (docs/SWEEPS.md, "Declared before the data").

A claim is known by its digest: what decides it (its sides, metric, direction, margin and baseline), not its name or
its words. ``sweep run`` (``--local`` and on Ray Tune) appends a row for each claim whose digest the record lacks,
with the time and the number of trials of the claim's configurations already finished then (kept in the results
folder, or finished in the sweep's own folder). The record lives in the results folder, committed with the kept
trials (a sweep without one keeps it in its own folder).

The report reads it: a claim whose digest was recorded with no trial of its configurations finished was declared
**before data**; one recorded with some finished, or absent from the record while finished trials of its
configurations are reported (added or changed since the last ``sweep run``), was declared **after data** and is
held as exploratory (``claims.Verdict.EXPLORATORY``). Trials with no record at all (a folder from before the record
was kept) are **not recorded**: the report says so and decides as before.
"""

from __future__ import annotations

import datetime
import hashlib
import json
from enum import Enum
from pathlib import Path

import pandas as pd

from train.sweep.claim_spec import Baseline, Claim, matches

DECLARED_FILE = "claims_declared.csv"
COLUMNS = ("declared", "claim", "digest", "trials_finished", "source")


class Declared(str, Enum):
    BEFORE = "before data"
    AFTER = "after data"
    UNRECORDED = "not recorded"


def digest(claim: Claim) -> str:
    """What decides ``claim`` (sides, metric, direction, margin, baseline) as a short hash: the same for the same
    claim however the file spells it (key order, ``0`` or ``0.0``), another for any change of substance."""
    content = {"a": _plain(claim.a), "b": _plain(claim.b), "metric": claim.metric,
               "expect": claim.direction.value, "margin": float(claim.margin)}
    text = json.dumps(content, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _plain(value):
    if isinstance(value, Baseline):
        return {"baseline": value.name}
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return sorted((_plain(v) for v in value), key=repr)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    return value


def record_folder(spec, folder: Path | None = None) -> Path:
    """Where the record of ``spec`` lives: its results folder, or the sweep's own folder without one."""
    from train.sweep.results import results_folder

    where = results_folder(spec, folder)
    return where if where is not None else Path(folder if folder is not None else spec.out)


def read_record(folder: Path) -> pd.DataFrame | None:
    """The record in ``folder``, or None where none is kept."""
    path = Path(folder) / DECLARED_FILE
    if not path.is_file():
        return None
    return pd.read_csv(path, dtype={"digest": str, "source": str}, keep_default_na=False)


def configurations_finished(spec, claim: Claim, keys) -> int:
    """How many of the finished trials ``keys`` ((configuration label, seed)) are of ``claim``'s configurations."""
    labels = {spec.label(values): values for values in spec.configurations()}
    sides = [side for side in (claim.a, claim.b) if isinstance(side, dict)]
    return sum(1 for label, _ in keys
               if label in labels and any(matches(side, labels[label]) for side in sides))


def finished_keys(trials: pd.DataFrame) -> set[tuple[str, int]]:
    """(configuration, seed) of the finished trials of a trials table."""
    if trials.empty or "finished" not in trials:
        return set()
    done = trials[trials["finished"].astype(bool)]
    return {(str(c), int(s)) for c, s in zip(done["configuration"], done["seed"])}


def declare(spec, folder: Path, when: str | None = None) -> int:
    """Record each claim of ``spec`` whose digest the record lacks, with the trials of its configurations finished
    now (kept in the results folder or finished in the sweep's ``folder``); returns the rows added. ``sweep run``
    calls it before its first trial starts."""
    from train.sweep.results import committed_keys, write_csv

    if not spec.claims:
        return 0
    where = record_folder(spec, folder)
    record = read_record(where)
    known = set() if record is None else set(record["digest"])
    own = Path(folder) / "trials.csv"
    keys = committed_keys(spec, folder) | (finished_keys(pd.read_csv(own)) if own.is_file() else set())
    when = when or datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    rows = [{"declared": when, "claim": c.name, "digest": digest(c),
             "trials_finished": configurations_finished(spec, c, keys), "source": "sweep run"}
            for c in spec.claims if digest(c) not in known]
    if rows:
        where.mkdir(parents=True, exist_ok=True)
        before = pd.DataFrame(columns=list(COLUMNS)) if record is None else record
        write_csv(pd.concat([before, pd.DataFrame(rows, columns=list(COLUMNS))], ignore_index=True),
                  where / DECLARED_FILE)
    return len(rows)


def status(spec, claim: Claim, trials: pd.DataFrame, record: pd.DataFrame | None) -> Declared:
    """Whether ``claim`` was declared before the data it is decided on (module docstring); ``trials`` is the table
    the report decides on."""
    if record is None:
        return Declared.UNRECORDED
    mine = record[record["digest"] == digest(claim)]
    if len(mine):
        return Declared.BEFORE if int(mine.iloc[0]["trials_finished"]) == 0 else Declared.AFTER
    return Declared.AFTER if configurations_finished(spec, claim, finished_keys(trials)) else Declared.UNRECORDED
