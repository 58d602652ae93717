"""The verdicts and figures the project publishes are the report's: each kept sweep's ``claims.csv`` is what
``colorgrid sweep report`` decides now from the kept ``trials.csv`` under the sweep file as shipped, and every number
the docs print about a kept claim is that report's, at the precision printed (``tests/docs_quotes.py``): each claims
table row, column by column; each quote (``VERDICT (figures)``) in the summary tables ("Where each finding stands",
section 1's scale table) and in README's and ASSISTANT_RECIPE's prose, for the claims ``QUOTES`` names. A row or
paragraph that quotes a verdict without a ``QUOTES`` entry fails, so does a kept claim no claims table quotes, and a
test of the test changes a copy of the page and expects each change to be caught. Prose on REPRODUCTION.md that
paraphrases a claim without the quote's shape is not read."""

import functools
import math
import re
from pathlib import Path

import pandas as pd
import pytest

from tests.docs_quotes import QUOTE, claims_row, quote
from train.sweep import claim_stats as st
from train.sweep.claim_table import table as claims_table
from train.sweep.claims import evaluate, sides
from train.sweep.declared import Declared
from train.sweep.results import committed, results_folder
from train.sweep.spec import load_sweep

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("docs/REPRODUCTION.md", "docs/ASSISTANT_RECIPE.md", "README.md")
PROSE = ("docs/ASSISTANT_RECIPE.md", "README.md")
"""Docs whose prose quotes are read too (REPRODUCTION's are in its tables)."""
T1, T8, RERUN = "table1_small", "table1_eighth", "table1_small_rerun"
K02, K0, AUX = ("annealing makes learning possible (kappa 0.2)", "annealing makes learning possible (kappa 0)",
                "the auxiliary loss helps (with annealing)")
RECIPE = "assistant_recipe"
QUOTES = {  # (doc, a table row's first cell or a paragraph's first 40 characters): the claims it quotes, in order
    ("docs/REPRODUCTION.md", "Table 1: annealing makes learning possible"): [(T1, K02), (T1, K0), (T8, K02), (T8, K0)],
    ("docs/REPRODUCTION.md", "Table 1: the auxiliary loss helps (annealed)"): [
        (T1, AUX), ("table1_small_confirm", AUX), ("table1_small_aux_confirm", AUX), (T8, AUX)],
    ("docs/REPRODUCTION.md", "Sparse rewards: the auxiliary loss prevents the collapse"): [
        ("sparse_small", "the auxiliary loss prevents the collapse"),
        ("sparse_small_confirm", "the auxiliary loss prevents the collapse")],
    ("docs/REPRODUCTION.md", "Sparse rewards: kappa 0.4 is worse than 0.2"): [
        ("sparse_small", "too much auxiliary loss is worse"),
        ("sparse_small_confirm", "too much auxiliary loss is worse")],
    ("docs/REPRODUCTION.md", "Cost of exploration: +1/-1 collects fewer blocks than +4/-1"): [
        ("exploration_small", "pessimism collects fewer goal blocks"),
        ("exploration_small", "pessimism collects fewer wrong blocks")],
    ("docs/REPRODUCTION.md", "Cost of exploration: +2/-1 learns somewhat"): [
        ("exploration_small", "neutral rewards learn somewhat")],
    ("docs/REPRODUCTION.md", "Cost of exploration: the copy follower beats every IPPO follower"): [
        ("exploration_small", f"the copy follower beats {r}") for r in ("+4/-1", "+2/-1", "+1/-1")],
    ("docs/REPRODUCTION.md", "Goal switch probability hardly changes the team's reward"): [
        ("switch_small", "switching hardly changes the team's reward")],
    ("docs/REPRODUCTION.md", "Potential shaping does not solve goal inference (pessimistic)"): [
        ("potential_small", "potential shaping does not raise the follower's net pickups"),
        ("potential_small", "potential shaping does not raise the follower's goal prediction")],
    ("docs/REPRODUCTION.md", "Distance shaping: the follower collapses to collecting nothing"): [
        ("shaping_small", "the shaped follower collects fewer goal blocks"),
        ("shaping_small", "the shaped follower collects fewer wrong blocks")],
    ("docs/REPRODUCTION.md", "Warm start: the warm pair scores better than a cold one"): [
        ("warmstart_small", "the warm pair beats the cold pair")],
    ("docs/REPRODUCTION.md", "Warm start: the warm follower adds to the team"): [
        ("warmstart_small", "a warm follower beats a fresh one (team)"),
        ("warmstart_small", "a warm follower beats a fresh one (follower)"),
        ("warmstart_small_confirm_kept", "the team scores more beside a warm follower than a fresh one")],
    ("docs/REPRODUCTION.md", "annealing makes learning possible, kappa 0.2"): [(T1, K02), (T8, K02)],
    ("docs/REPRODUCTION.md", "annealing makes learning possible, kappa 0"): [(T1, K0), (T8, K0)],
    ("docs/REPRODUCTION.md", "the auxiliary loss helps, annealed"): [(T1, AUX), (T8, AUX)],
    ("docs/ASSISTANT_RECIPE.md", "**The evidence: the last step's inputs**"): [
        (RECIPE, "last-step inputs are needed"), (RECIPE, "memory is needed")],
    ("docs/ASSISTANT_RECIPE.md", "**A trained belief: the auxiliary goal l"): [
        (RECIPE, "the auxiliary loss is needed")],
    ("docs/ASSISTANT_RECIPE.md", "**A way to act on it: goal planes weight"): [
        (RECIPE, "belief-weighted goal planes are needed")],
    ("docs/ASSISTANT_RECIPE.md", "**Its own block reward, for the last 3 n"): [(RECIPE, "its own reward is needed")],
    ("docs/ASSISTANT_RECIPE.md", "**Not shown to be needed: the annealed p"): [
        (RECIPE, "the recipe without annealing matches the recipe")],
    ("docs/ASSISTANT_RECIPE.md", "**Not shown to be needed: the A* partner"): [(RECIPE, "the A* partner is needed")],
    ("docs/ASSISTANT_RECIPE.md", "**`sweeps/assistant_partners_varied.toml"): [
        ("assistant_partners_varied", c) for c in (
            "partners that vary beat A* alone", "leaders at several skill levels beat A* alone",
            "the mixture beats bayes-people (net)", "the mixture errs as bayes-people does",
            "the mixture beats ippo-people (net)")],
    ("docs/ASSISTANT_RECIPE.md", "The paper's partner for a learning follo"): [
        (RECIPE, "the recipe beside an IPPO leader beats the copy follower")],
}


def kept_sweeps() -> dict[str, Path]:
    """``{results folder name: sweep file}`` for every shipped sweep file whose kept results include claims."""
    found = {}
    for path in sorted((ROOT / "sweeps").glob("*.toml")):
        match = re.search(r'^results\s*=\s*"([^"]+)"', path.read_text(), re.MULTILINE)
        if match and (ROOT / match.group(1) / "claims.csv").is_file():
            found[Path(match.group(1)).name] = path
    return found


@functools.cache
def recomputed(sweep: str):
    """``(spec, trials, claims table)`` of the kept sweep ``sweep``, the report recomputed from its kept trials."""
    spec = load_sweep(kept_sweeps()[sweep])
    trials, _ = committed(spec)
    return spec, trials, claims_table(evaluate(spec, trials))


def report_rows() -> dict[tuple[str, str], dict]:
    return {(sweep, row["claim"]): row for sweep in kept_sweeps()
            for row in recomputed(sweep)[2].to_dict("records")}


def first_seeds(sweep: str, claim_name: str):
    """``k -> (difference, p)`` of the claim on each side's first ``k`` seeds (an earlier look's figures)."""
    spec, trials, _ = recomputed(sweep)
    claim = next(c for c in spec.claims if c.name == claim_name)

    def on(k: int):
        a, b, kind = sides(spec, claim, trials, results_folder(spec))
        a = a.keep(sorted(a.seeds)[:k])
        b = b if isinstance(b, float) else b.keep(sorted(b.seeds)[:k])
        test = st.t_test(kind, a.values, b if isinstance(b, float) else b.values, 0.95)
        return test.difference, test.p
    return on


def units(doc: str, text: str):
    """``(where, key, cells or None, text)``: each table row, and each prose paragraph or bullet of a PROSE doc."""
    lines, header, block = text.splitlines(), [], []
    for number, line in enumerate(lines, 1):
        if line.startswith("|"):
            cells = [c.strip() for c in re.split(r" \| ", line.strip().strip("|").strip())]
            if number < len(lines) and lines[number].startswith("|---"):
                header = cells
            elif not line.startswith("|---"):
                yield f"{doc}:{number}", cells[0], (header, cells), line
        if doc in PROSE:
            if not line.strip() or line.startswith(("|", "#", "- ")):
                if block:
                    yield block[0][0], block[0][1].removeprefix("- ")[:40], None, " ".join(b[1] for b in block)
                block = [(f"{doc}:{number}", line)] if line.startswith("- ") else []
            else:
                block.append((f"{doc}:{number}", line))


def problems(texts: dict[str, str]) -> list[str]:
    """Every disagreement between the docs' ``texts`` (``{doc: text}``) and the recomputed reports."""
    rows, out, found = report_rows(), [], set()
    names = {claim for _, claim in rows}
    for doc, text in texts.items():
        sweep = None
        for number, line in enumerate(text.splitlines(), 1):
            linked = re.findall(r"reproduction/([a-z0-9_]+)/", line)
            sweep = linked[-1] if linked else sweep
            if line.startswith("| ") and linked == []:
                first = line.split("|")[1].strip()
                if any(first == n or first.startswith(n + " (") for n in names):
                    found.add((doc, number, sweep))
        for where, key, table, body in units(doc, text):
            number = int(where.rpartition(":")[2])
            claim = None if table is None else next(
                (n for n in names if key == n or key.startswith(n + " (")), None)
            if table is not None and claim is not None and table[0][:1] == ["claim"]:
                sweep = next(s for d, n, s in found if d == doc and n == number)
                if (sweep, claim) not in rows:
                    out.append(f"{where}: {claim!r} below a link to {sweep}, not its claim")
                    continue
                out += [f"{where}: {claim}: {p}" for p in claims_row(*table, rows[sweep, claim])]
                continue
            quotes, claims = QUOTE.findall(body), QUOTES.get((doc, key))
            if claims is None:
                out += [f"{where}: quotes {len(quotes)} verdicts; QUOTES does not say of which claims"] if quotes else []
                continue
            if len(quotes) != len(claims):
                out.append(f"{where}: {len(quotes)} quotes, QUOTES names {len(claims)} claims")
                continue
            for (verdict, figures), (sweep, claim) in zip(quotes, claims):
                out += [f"{where}: {claim}: {p}" for p in quote(verdict, figures, rows[sweep, claim],
                                                               first_seeds(sweep, claim))]
    keys = {(doc, key) for doc, text in texts.items() for _, key, _, _ in units(doc, text)}
    out += [f"{doc}: no row or paragraph starts {key!r} (QUOTES)" for doc, key in QUOTES if (doc, key) not in keys]
    return out


def docs() -> dict[str, str]:
    return {doc: (ROOT / doc).read_text() for doc in DOCS}


def test_the_kept_sweeps_are_found():
    assert {"table1_small", "table1_eighth", "exploration_small", "assistant_recipe"} <= set(kept_sweeps())


@pytest.mark.parametrize("sweep", kept_sweeps())
def test_kept_claims_are_what_the_report_decides_from_the_kept_trials(sweep, monkeypatch):
    monkeypatch.chdir(ROOT)
    spec, _, now = recomputed(sweep)
    kept = pd.read_csv(results_folder(spec) / "claims.csv")
    assert list(now["claim"]) == list(kept["claim"]), "the file's claims are not the kept ones: run sweep report"
    for column in ("verdict", "declared", "looks", "n_a", "n_b", "test"):
        assert list(now[column]) == list(kept[column]), column
    for column in ("difference", "ci_low", "ci_high", "p", "p_equivalence", "p_outside", "p_adjusted"):
        for a, b in zip(now[column], kept[column]):  # to the CSV's precision
            assert (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, rel=1e-9, abs=1e-12), column
    assert Declared.UNRECORDED.value not in set(now["declared"]), "a kept claim without a declaration on record"


def test_every_number_the_docs_print_about_a_claim_is_the_reports():
    assert problems(docs()) == []


def test_every_kept_claim_is_quoted_in_a_claims_table():
    rows, quoted = report_rows(), set()
    for doc, text in docs().items():
        sweep = None
        for line in text.splitlines():
            linked = re.findall(r"reproduction/([a-z0-9_]+)/", line)
            sweep = linked[-1] if linked else sweep
            first = line.split("|")[1].strip() if line.startswith("| ") else ""
            quoted |= {(sweep, c) for _, c in rows if first == c or first.startswith(c + " (")}
    assert set(rows) <= quoted, f"kept claims no claims table quotes: {sorted(set(rows) - quoted)}"


MUTATIONS = [  # (doc, a line's start, what it holds, what it is changed to)
    ("docs/REPRODUCTION.md", "| annealing makes learning possible (kappa 0) | aux=0.0, annealing=4M-10M: - (0)",
     "| Welch | - |", "| Welch | +1.00 |"),  # a side with no finished trial has no difference
    ("docs/REPRODUCTION.md", "| annealing makes learning possible (kappa 0.2) | aux=0.2, annealing=4M-10M: +54.54",
     "| -0.20 (no interval at one seed) |", "| - |"),
    ("docs/REPRODUCTION.md", "| the auxiliary loss helps (with annealing) | aux=0.2", "| Welch | -19.09", "| Welch | -19.19"),
    ("docs/REPRODUCTION.md", "| the auxiliary loss helps (with annealing) | aux=0.2", "[-32.17,", "[-32.71,"),
    ("docs/REPRODUCTION.md", "| the auxiliary loss helps (with annealing) | aux=0.2", "| 0.0105 |", "| 0.0150 |"),
    ("docs/REPRODUCTION.md", "| Sparse rewards: kappa 0.4 is worse than 0.2 |", None, "reproduced (p 0.001)"),
    ("docs/ASSISTANT_RECIPE.md", "| its own reward is needed |", "| 0.0469 |", "| 0.0496 |"),
]


@pytest.mark.parametrize("doc, start, old, new", MUTATIONS)
def test_a_changed_number_or_verdict_on_a_copy_of_the_page_is_caught(doc, start, old, new):
    texts = docs()
    lines = texts[doc].splitlines()
    number = next(i for i, line in enumerate(lines) if line.startswith(start))
    if old is None:  # the row's verdict column: its quotes replaced by one made-up verdict
        cells = lines[number].split(" | ")
        cells[3] = new
        changed = " | ".join(cells)
    else:
        assert old in lines[number]
        changed = lines[number].replace(old, new, 1)
    assert changed != lines[number]
    texts[doc] = "\n".join(lines[:number] + [changed] + lines[number + 1:])
    found = problems(texts)
    assert found and all(f"{doc}:{number + 1}:" in p for p in found), found
