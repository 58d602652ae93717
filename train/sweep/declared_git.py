"""The record of declarations (``train.sweep.declared``) for claims kept before ``sweep run`` wrote one, read from git
history: a claim counts as declared at the oldest commit of the unbroken run of commits, up to the newest, whose
sweep file holds it with the same digest, and its data are the trials of its configurations the results folder kept
at that commit. Trials in that very commit, or before it, make it declared after data; trials kept only in later
commits leave it before data, as far as git can tell (a trial finished but not yet committed when the claim was
committed would not show). The date written is that commit's, not a moment of declaration.

``python -m train.sweep.declared_git sweeps/FILE.toml ...`` writes the rows of each file's claims that its results
folder's record lacks (docs/SWEEPS.md, "Declared before the data").
"""

from __future__ import annotations

import io
import subprocess
import sys
import tomllib
from pathlib import Path

import pandas as pd

from train.sweep.claim_spec import matches
from train.sweep.declared import COLUMNS, DECLARED_FILE, digest, read_record


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], check=True, capture_output=True, text=True).stdout


def versions(path: Path) -> list[tuple[str, str, str]]:
    """``(commit, committer date, path then)`` of each commit that changed the sweep file, newest first (renames
    followed)."""
    out, lines = [], _git("log", "--follow", "--name-only", "--format=%x00%H %cI", "--", str(path)).split("\x00")
    for block in lines[1:]:
        head, *names = [line for line in block.splitlines() if line.strip()]
        commit, date = head.split()
        out.append((commit, date, names[0] if names else str(path)))
    return out


def digests_at(commit: str, path: str) -> set[str]:
    """The digests of the claims of the sweep file ``path`` at ``commit`` (none where it does not parse now)."""
    from train.sweep.spec import parse_sweep

    try:
        text = _git("show", f"{commit}:{path}")
        spec = parse_sweep(tomllib.loads(text), Path(path), text)
    except Exception:  # a version the current parser refuses declares nothing it can vouch for
        return set()
    return {digest(c) for c in spec.claims}


def kept_at(commit: str, results: Path) -> pd.DataFrame:
    """The finished trials the results folder kept at ``commit`` (empty before it kept any)."""
    try:
        text = _git("show", f"{commit}:{results.as_posix()}/trials.csv")
    except subprocess.CalledProcessError:
        return pd.DataFrame()
    trials = pd.read_csv(io.StringIO(text))
    return trials[trials["finished"].astype(bool)] if "finished" in trials else trials


def backfill(spec_path: Path) -> list[dict]:
    """The record's rows, from git history, for the claims of the sweep file at ``spec_path`` (as committed)."""
    from train.sweep.spec import load_sweep

    spec = load_sweep(spec_path)
    history = versions(spec_path)
    found = {commit: digests_at(commit, path) for commit, _, path in history}
    rows = []
    for claim in spec.claims:
        mine, since = digest(claim), None
        for commit, date, _ in history:
            if mine not in found[commit]:
                break
            since = (commit, date)
        if since is None:
            continue  # not committed as it stands: no date git can give
        trials = kept_at(since[0], spec.results)
        sides = [s for s in (claim.a, claim.b) if isinstance(s, dict)]
        count = sum(1 for _, row in trials.iterrows() if any(matches(s, row) for s in sides))
        rows.append({"declared": since[1], "claim": claim.name, "digest": mine, "trials_finished": count,
                     "source": f"git: the claim as it stands since {since[0][:7]}, its results folder keeping "
                               f"{count} trials of its configurations then"})
    return rows


def main(paths: list[str]) -> None:
    from train.sweep.results import write_csv

    for path in map(Path, paths):
        from train.sweep.spec import load_sweep

        where = load_sweep(path).results
        record = read_record(where)
        known = set() if record is None else set(record["digest"])
        rows = [r for r in backfill(path) if r["digest"] not in known]
        if rows:
            before = pd.DataFrame(columns=list(COLUMNS)) if record is None else record
            write_csv(pd.concat([before, pd.DataFrame(rows, columns=list(COLUMNS))], ignore_index=True),
                      where / DECLARED_FILE)
        print(f"{path}: {len(rows)} claims recorded from git history in {where / DECLARED_FILE}")


if __name__ == "__main__":
    main(sys.argv[1:])
