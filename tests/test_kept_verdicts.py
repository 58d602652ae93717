"""The verdicts the project publishes are the report's: each kept sweep's ``claims.csv`` is what ``colorgrid sweep
report`` decides now from the kept ``trials.csv`` under the sweep file as shipped, and every docs table row whose
first cell is a claim's name (the claims tables the docs quote from the reports) gives that verdict. A change to
the rule, to a sweep file's claims or seeds, or to a kept table that is not carried into the kept claims and those
rows fails here, and so does a kept claim that no docs table quotes. Rows that paraphrase a claim (the summary
tables) and verdicts quoted in prose are not read."""

import math
import re
from pathlib import Path

import pandas as pd
import pytest

from train.sweep.claim_table import table as claims_table
from train.sweep.claims import Verdict, evaluate
from train.sweep.results import committed, results_folder
from train.sweep.spec import load_sweep

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("docs/REPRODUCTION.md", "docs/ASSISTANT_RECIPE.md", "README.md")


def kept_sweeps() -> dict[str, Path]:
    """``{results folder name: sweep file}`` for every shipped sweep file whose kept results include claims."""
    found = {}
    for path in sorted((ROOT / "sweeps").glob("*.toml")):
        text = path.read_text()
        match = re.search(r'^results\s*=\s*"([^"]+)"', text, re.MULTILINE)
        if match and (ROOT / match.group(1) / "claims.csv").is_file():
            found[Path(match.group(1)).name] = path
    return found


def kept_claims(sweep: str) -> pd.DataFrame:
    """The kept ``claims.csv`` of the results folder ``docs/reproduction/<sweep>``."""
    return pd.read_csv(ROOT / "docs" / "reproduction" / sweep / "claims.csv")


def test_the_kept_sweeps_are_found():
    assert {"table1_small", "table1_eighth", "exploration_small", "assistant_recipe"} <= set(kept_sweeps())


@pytest.mark.parametrize("path", kept_sweeps().values(), ids=lambda p: p.stem)
def test_kept_claims_are_what_the_report_decides_from_the_kept_trials(path, monkeypatch):
    monkeypatch.chdir(ROOT)
    spec = load_sweep(path)
    trials, _ = committed(spec)
    kept = pd.read_csv(results_folder(spec) / "claims.csv")
    now = claims_table(evaluate(spec, trials))
    assert list(now["claim"]) == list(kept["claim"]), "the file's claims are not the kept ones: run sweep report"
    assert list(now["verdict"]) == list(kept["verdict"])
    assert list(now["looks"]) == list(kept["looks"]) and list(now["n_a"]) == list(kept["n_a"])
    assert list(now["n_b"]) == list(kept["n_b"]) and list(now["test"]) == list(kept["test"])
    for column in ("difference", "ci_low", "ci_high", "p", "p_equivalence", "p_adjusted"):  # to the CSV's precision
        for a, b in zip(now[column], kept[column]):
            assert (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, rel=1e-9, abs=1e-12), column


def quoted_rows() -> list[tuple[str, int, str, str, str]]:
    """Every docs table row whose first cell names a kept claim: ``(doc, line, sweep, claim, verdict cell)``. The
    sweep is the last one the doc links (``reproduction/<sweep>/``) at or above the row."""
    names = {}
    for sweep in kept_sweeps():
        for claim in kept_claims(sweep)["claim"]:
            names.setdefault(claim, set()).add(sweep)
    rows = []
    for doc in DOCS:
        sweep = None
        for number, line in enumerate((ROOT / doc).read_text().splitlines(), 1):
            linked = re.findall(r"reproduction/([a-z0-9_]+)/", line)
            sweep = linked[-1] if linked else sweep
            if not line.startswith("| "):
                continue
            first = line.split("|")[1].strip()
            claim = next((n for n in names if first == n or first.startswith(n + " (")), None)
            if claim is not None:
                rows.append((doc, number, sweep, claim, line.rstrip().rstrip("|").split("|")[-1].strip().strip("*")))
    return rows


def test_every_docs_table_row_quotes_the_reports_verdict():
    rows = quoted_rows()
    assert {doc for doc, *_ in rows} >= {"docs/REPRODUCTION.md", "docs/ASSISTANT_RECIPE.md"}
    verdicts = {}
    for sweep in kept_sweeps():
        kept = kept_claims(sweep)
        verdicts.update({(sweep, c): v for c, v in zip(kept["claim"], kept["verdict"])})
    for doc, number, sweep, claim, cell in rows:
        assert (sweep, claim) in verdicts, f"{doc}:{number}: {claim!r} quoted below a link to {sweep}, not its claim"
        assert cell in {v.value for v in Verdict}, f"{doc}:{number}: the last cell {cell!r} is not a verdict"
        report = verdicts[sweep, claim]
        assert cell == report, f"{doc}:{number}: {claim!r} says {cell!r}, the report {report!r}"


def test_every_kept_claim_is_quoted_in_a_docs_table():
    quoted = {(sweep, claim) for _, _, sweep, claim, _ in quoted_rows()}
    for sweep in kept_sweeps():
        for claim in kept_claims(sweep)["claim"]:
            assert (sweep, claim) in quoted, f"{sweep}: the claim {claim!r} has no row in a claims table of {DOCS}"
